//! What media deliver to an attached endpoint: a time-stamped frame or packet, tagged
//! with the endpoint's interface index.
//!
//! An inbox holds at most [`INBOX_DEPTH`] arrivals not yet taken, like a controller's
//! receive FIFO or a socket's receive buffer: a medium delivering to a full inbox loses the
//! arrival, and counts it as the endpoint's `rx_overflow`.
//!
//! The inbox is a queue under a mutex and one waker: a medium delivers every frame through
//! it, and a bounded tokio channel cost about twice as much per frame (a semaphore permit
//! taken and given back under its lock, besides the queue and the waker).
//!
//! A medium may deliver an arrival *quietly* ([`InboxTx::send_all`]): a CAN frame whose
//! packet's next frame is already on the wire, which nothing in the node acts on before
//! that next one arrives. A quiet arrival is queued without waking the receiver, when the receiver said it
//! takes quiet arrivals ([`InboxRx::take_quiet`]: the node task, which handles them before
//! its next timer or command, in the order they came). A receiver that did not (a bridge
//! to the outside, forwarding frame by frame) is woken for every arrival.

use std::collections::VecDeque;
use std::future::poll_fn;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Poll, Waker};

use csp::cfp::CanFrame;
use csp::{Packet, SimTime};

/// A frame or packet arriving at an endpoint.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arrival {
    /// A CAN frame (CFP fragment).
    Can(CanFrame),
    /// A whole CSP packet.
    Packet(Packet),
}

/// An arrival with its exact simulated time and the receiving interface.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Inbound {
    /// When the last bit arrived.
    pub t: SimTime,
    /// Interface index of the receiving endpoint.
    pub iface: usize,
    /// What arrived.
    pub what: Arrival,
}

/// Arrivals an inbox holds before it loses more: 1024 frames are about 130 ms of a
/// saturated 1 Mbit/s bus, several times what a node's task takes to catch up.
pub const INBOX_DEPTH: usize = 1024;

/// The sending half of an endpoint's inbox; clones send to the same inbox, and the inbox
/// closes when the last one is dropped.
#[derive(Debug)]
pub struct InboxTx(Arc<Shared>);

/// The receiving half of an endpoint's inbox.
#[derive(Debug)]
pub struct InboxRx(Arc<Shared>);

#[derive(Debug)]
struct Shared {
    state: Mutex<State>,
}

#[derive(Debug)]
struct State {
    queue: VecDeque<Inbound>,
    depth: usize,
    senders: usize,
    receiver: bool,
    /// The receiver's task while it waits for an arrival.
    waker: Option<Waker>,
    /// Whether the receiver takes quiet arrivals ([`InboxRx::take_quiet`]).
    quiet_ok: bool,
    /// How many arrivals at the front of the queue came quietly (every one before the
    /// first that woke the receiver).
    quiet_front: usize,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Nothing panics while holding the lock; a poisoned inbox is still a queue.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// Why an arrival did not get into an inbox.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum InboxError {
    /// The inbox holds [`INBOX_DEPTH`] arrivals: the arrival is lost.
    #[error("inbox full")]
    Full,
    /// Nobody reads the inbox any more.
    #[error("inbox closed")]
    Closed,
}

/// Why [`InboxRx::try_recv`] returned nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TryRecvError {
    /// Nothing waiting now.
    #[error("inbox empty")]
    Empty,
    /// Nothing waiting, and every sender is gone.
    #[error("inbox closed")]
    Closed,
}

impl InboxTx {
    /// Put an arrival in the inbox, never waiting: lost when the inbox is full.
    pub fn send(&self, a: Inbound) -> Result<(), InboxError> {
        let waker = {
            let mut st = self.0.lock();
            st.push(a, false)?;
            st.waker.take()
        };
        if let Some(w) = waker {
            w.wake();
        }
        Ok(())
    }

    /// [`send`](Self::send) each of `arrivals` in order, under one lock, emptying it; an
    /// arrival marked `true` is quiet: it needs no attention before the next one (a CAN
    /// frame whose packet's next frame is on the wire) and is queued without waking a
    /// receiver that takes quiet arrivals. How many were lost to a full inbox.
    pub fn send_all(&self, arrivals: &mut Vec<(Inbound, bool)>) -> usize {
        let mut full = 0;
        let mut wake = false;
        let waker = {
            let mut st = self.0.lock();
            for (a, quiet) in arrivals.drain(..) {
                match st.push(a, quiet) {
                    Ok(woken) => wake |= woken,
                    Err(InboxError::Full) => full += 1,
                    Err(InboxError::Closed) => {}
                }
            }
            if wake { st.waker.take() } else { None }
        };
        if let Some(w) = waker {
            w.wake();
        }
        full
    }
}

impl State {
    /// Queue `a` (quietly if `quiet` and the receiver takes quiet arrivals); whether the
    /// receiver is to be woken.
    fn push(&mut self, a: Inbound, quiet: bool) -> Result<bool, InboxError> {
        if !self.receiver {
            return Err(InboxError::Closed);
        }
        if self.queue.len() >= self.depth {
            return Err(InboxError::Full);
        }
        let quiet = quiet && self.quiet_ok;
        if quiet && self.quiet_front == self.queue.len() {
            self.quiet_front += 1;
        }
        self.queue.push_back(a);
        Ok(!quiet)
    }
}

impl Clone for InboxTx {
    fn clone(&self) -> Self {
        self.0.lock().senders += 1;
        InboxTx(Arc::clone(&self.0))
    }
}

impl Drop for InboxTx {
    fn drop(&mut self) {
        let waker = {
            let mut st = self.0.lock();
            st.senders -= 1;
            if st.senders == 0 {
                st.waker.take()
            } else {
                None
            }
        };
        if let Some(w) = waker {
            w.wake();
        }
    }
}

impl InboxRx {
    /// The next arrival; `None` once the inbox is empty and every sender is gone.
    /// Cancel-safe: an arrival is taken only by the call that returns it.
    pub async fn recv(&mut self) -> Option<Inbound> {
        poll_fn(|cx| {
            let mut st = self.0.lock();
            if let Some(a) = st.queue.pop_front() {
                st.quiet_front = st.quiet_front.saturating_sub(1);
                return Poll::Ready(Some(a));
            }
            if st.senders == 0 {
                return Poll::Ready(None);
            }
            match &mut st.waker {
                Some(w) if w.will_wake(cx.waker()) => {}
                w => *w = Some(cx.waker().clone()),
            }
            Poll::Pending
        })
        .await
    }

    /// Wait for arrivals and move up to `max` of them (at least one) to the back of `buf`;
    /// 0 once the inbox is empty and every sender is gone. Cancel-safe, as [`recv`](Self::recv).
    /// Quiet arrivals alone do not end the wait of a receiver that takes them: it takes
    /// them ([`try_recv_quiet`](Self::try_recv_quiet)) when something else wakes it, so
    /// that when it does depends on what woke it, never on when it was last polled.
    pub async fn recv_many(&mut self, buf: &mut VecDeque<Inbound>, max: usize) -> usize {
        poll_fn(|cx| {
            let mut st = self.0.lock();
            let quiet_only = st.quiet_ok && st.quiet_front == st.queue.len();
            if !st.queue.is_empty() && (!quiet_only || st.senders == 0) {
                let n = st.queue.len().min(max.max(1));
                buf.extend(st.queue.drain(..n));
                st.quiet_front = st.quiet_front.saturating_sub(n);
                return Poll::Ready(n);
            }
            if st.senders == 0 {
                return Poll::Ready(0);
            }
            match &mut st.waker {
                Some(w) if w.will_wake(cx.waker()) => {}
                w => *w = Some(cx.waker().clone()),
            }
            Poll::Pending
        })
        .await
    }

    /// The next arrival if there is one now.
    pub fn try_recv(&mut self) -> Result<Inbound, TryRecvError> {
        let mut st = self.0.lock();
        match st.queue.pop_front() {
            Some(a) => {
                st.quiet_front = st.quiet_front.saturating_sub(1);
                Ok(a)
            }
            None if st.senders == 0 => Err(TryRecvError::Closed),
            None => Err(TryRecvError::Empty),
        }
    }

    /// From now on, take quiet arrivals ([`InboxTx::send_all`]) without being woken: the
    /// receiver promises to take them ([`try_recv_quiet`](Self::try_recv_quiet)) before it
    /// acts on anything else.
    pub fn take_quiet(&mut self) {
        self.0.lock().quiet_ok = true;
    }

    /// The first arrival if it came quietly (it would have been taken before anything
    /// that happens now, had it woken the receiver).
    pub fn try_recv_quiet(&mut self) -> Option<Inbound> {
        let mut st = self.0.lock();
        if st.quiet_front == 0 {
            return None;
        }
        st.quiet_front -= 1;
        st.queue.pop_front()
    }

    /// Whether the first arrival came quietly.
    pub fn has_quiet(&self) -> bool {
        self.0.lock().quiet_front > 0
    }

    /// Arrivals waiting.
    pub fn len(&self) -> usize {
        self.0.lock().queue.len()
    }

    /// Whether no arrival is waiting.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Drop for InboxRx {
    fn drop(&mut self) {
        let mut st = self.0.lock();
        st.receiver = false;
        st.queue.clear();
        st.quiet_front = 0;
        st.waker = None;
    }
}

/// A new inbox of [`INBOX_DEPTH`] arrivals.
pub fn inbox() -> (InboxTx, InboxRx) {
    inbox_with(INBOX_DEPTH)
}

/// A new inbox of `depth` arrivals.
pub fn inbox_with(depth: usize) -> (InboxTx, InboxRx) {
    let shared = Arc::new(Shared {
        state: Mutex::new(State {
            queue: VecDeque::new(),
            depth: depth.max(1),
            senders: 1,
            receiver: true,
            waker: None,
            quiet_ok: false,
            quiet_front: 0,
        }),
    });
    (InboxTx(Arc::clone(&shared)), InboxRx(shared))
}

// The state a snapshot saves (docs/snapshots.md).
snap::tagged_enum!(Arrival { Can(f), Packet(p) });
snap::fields!(Inbound { t, iface, what });

/// A look at an inbox for snapshots ([`InboxRx::state`]): what it holds, and how many of
/// those came quietly. It neither sends nor receives (it keeps the inbox neither open nor
/// closed).
#[derive(Debug, Clone)]
pub struct InboxState(Arc<Shared>);

impl InboxRx {
    /// A look at this inbox for snapshots.
    pub fn state(&self) -> InboxState {
        InboxState(Arc::clone(&self.0))
    }
}

/// The arrivals waiting (at a quiescent point only frames that came quietly, which woke
/// nobody), and how many came quietly; loaded into an inbox as built (empty), they wait
/// there as they did.
impl snap::Snap for InboxState {
    fn save(&self, w: &mut snap::Writer) {
        let st = self.0.lock();
        st.queue.save(w);
        st.quiet_front.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let mut st = self.0.lock();
        st.queue.load(r)?;
        st.quiet_front.load(r)?;
        if st.quiet_front > st.queue.len() || st.queue.len() > st.depth {
            return Err(snap::SnapError::Bad {
                what: "inbox",
                at: r.at(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A quiet arrival on its own.
    fn send_quiet(tx: &InboxTx, a: Inbound) -> Result<(), InboxError> {
        match tx.send_all(&mut vec![(a, true)]) {
            0 => Ok(()),
            _ => Err(InboxError::Full),
        }
    }

    fn frame(t: u64) -> Inbound {
        Inbound {
            t: SimTime::from_ns(t),
            iface: 0,
            what: Arrival::Can(CanFrame::new(1, &[t as u8]).unwrap()),
        }
    }

    #[test]
    fn holds_depth_arrivals_in_order_and_refuses_more() {
        let (tx, mut rx) = inbox_with(2);
        assert_eq!(tx.send(frame(1)), Ok(()));
        assert_eq!(tx.send(frame(2)), Ok(()));
        assert_eq!(tx.send(frame(3)), Err(InboxError::Full));
        assert_eq!(rx.len(), 2);
        assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(1));
        assert_eq!(tx.send(frame(4)), Ok(()));
        assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(2));
        assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(4));
        assert_eq!(rx.try_recv(), Err(TryRecvError::Empty));
    }

    #[test]
    fn closes_when_the_last_sender_goes_after_what_is_waiting() {
        let (tx, mut rx) = inbox();
        let tx2 = tx.clone();
        drop(tx);
        tx2.send(frame(1)).unwrap();
        drop(tx2);
        assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(1));
        assert_eq!(rx.try_recv(), Err(TryRecvError::Closed));
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        assert_eq!(rt.block_on(rx.recv()), None);
    }

    #[test]
    fn a_send_to_a_dropped_receiver_is_refused() {
        let (tx, rx) = inbox();
        drop(rx);
        assert_eq!(tx.send(frame(1)), Err(InboxError::Closed));
    }

    /// A receiver waiting in `recv` is woken by a send from another task, and by the last
    /// sender going.
    #[test]
    fn a_waiting_receiver_is_woken() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        rt.block_on(async {
            let (tx, mut rx) = inbox();
            let got = tokio::spawn(async move {
                let a = rx.recv().await.map(|a| a.t);
                let b = rx.recv().await.map(|a| a.t);
                (a, b)
            });
            tokio::task::yield_now().await;
            tx.send(frame(7)).unwrap();
            tokio::task::yield_now().await;
            drop(tx);
            assert_eq!(got.await.unwrap(), (Some(SimTime::from_ns(7)), None));
        });
    }

    /// Quiet arrivals wake only a receiver that does not take them; one that does finds
    /// them first in the queue, in order, and only those before the first loud one count as
    /// quiet.
    #[test]
    fn quiet_arrivals_wake_only_a_receiver_that_does_not_take_them() {
        use std::sync::atomic::{AtomicBool, Ordering};
        struct Flag(AtomicBool);
        impl std::task::Wake for Flag {
            fn wake(self: Arc<Self>) {
                self.0.store(true, Ordering::SeqCst);
            }
        }
        for takes in [false, true] {
            let (tx, mut rx) = inbox();
            if takes {
                rx.take_quiet();
            }
            let flag = Arc::new(Flag(AtomicBool::new(false)));
            let waker = Waker::from(Arc::clone(&flag));
            let mut cx = std::task::Context::from_waker(&waker);
            {
                let mut recv = std::pin::pin!(rx.recv());
                assert!(recv.as_mut().poll(&mut cx).is_pending());
            }
            send_quiet(&tx, frame(1)).unwrap();
            assert_eq!(
                flag.0.load(Ordering::SeqCst),
                !takes,
                "takes quiet: {takes}"
            );
            send_quiet(&tx, frame(2)).unwrap();
            tx.send(frame(3)).unwrap();
            send_quiet(&tx, frame(4)).unwrap();
            let quiet: Vec<_> = std::iter::from_fn(|| rx.try_recv_quiet())
                .map(|a| a.t.as_ns())
                .collect();
            assert_eq!(quiet, if takes { vec![1, 2] } else { vec![] });
            if !takes {
                assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(1));
                assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(2));
            }
            assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(3));
            assert_eq!(rx.try_recv_quiet(), None, "behind a loud one, or not taken");
            assert_eq!(rx.try_recv().unwrap().t, SimTime::from_ns(4));
        }
    }

    /// Quiet arrivals alone do not end the wait of a receiver that takes them (what woke
    /// it decides when it takes them, not when it was last polled); one loud arrival behind
    /// them does, and brings them along in order.
    #[test]
    fn quiet_arrivals_alone_do_not_end_a_wait() {
        let (tx, mut rx) = inbox();
        rx.take_quiet();
        send_quiet(&tx, frame(1)).unwrap();
        send_quiet(&tx, frame(2)).unwrap();
        let waker = Waker::noop();
        let mut cx = std::task::Context::from_waker(waker);
        let mut out = VecDeque::new();
        {
            let mut recv = std::pin::pin!(rx.recv_many(&mut out, 8));
            assert!(recv.as_mut().poll(&mut cx).is_pending());
        }
        assert!(rx.has_quiet());
        tx.send(frame(3)).unwrap();
        {
            let mut recv = std::pin::pin!(rx.recv_many(&mut out, 8));
            assert_eq!(recv.as_mut().poll(&mut cx), Poll::Ready(3));
        }
        let ts: Vec<_> = out.iter().map(|a| a.t.as_ns()).collect();
        assert_eq!(ts, [1, 2, 3]);
    }

    /// A batch goes in in order, under the depth (the rest counted as lost), quiet ones
    /// counted at the front, and `recv_many` takes them out in order.
    #[test]
    fn a_batch_goes_in_and_comes_out_in_order() {
        let (tx, mut rx) = inbox_with(3);
        rx.take_quiet();
        let mut batch = vec![
            (frame(1), true),
            (frame(2), false),
            (frame(3), true),
            (frame(4), false),
        ];
        assert_eq!(
            tx.send_all(&mut batch),
            1,
            "the fourth finds the inbox full"
        );
        assert!(batch.is_empty());
        assert_eq!(rx.try_recv_quiet().map(|a| a.t.as_ns()), Some(1));
        assert_eq!(
            rx.try_recv_quiet(),
            None,
            "2 woke the receiver: 3 is behind it"
        );
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let mut out = VecDeque::new();
        assert_eq!(rt.block_on(rx.recv_many(&mut out, 8)), 2);
        let ts: Vec<_> = out.iter().map(|a| a.t.as_ns()).collect();
        assert_eq!(ts, [2, 3]);
        drop(tx);
        assert_eq!(rt.block_on(rx.recv_many(&mut out, 8)), 0, "closed");
    }
}
