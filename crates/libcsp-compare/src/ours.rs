//! Our side: timed loops over `m6p-csp` (see the crate documentation for what one
//! iteration is). Inputs pass through [`black_box`] so that nothing is hoisted out of the
//! loop or computed at compile time.

use std::hint::black_box;
use std::time::{Duration, Instant};

use csp::cfp::{CSP_CAN_MTU, CanFrame, Fragmenter};
use csp::client::Client;
use csp::node::{Node, NodeConfig};
use csp::{Header, Packet, SimTime, crc32, kiss};

use crate::{Case, Error, NODE_ADDR, Op, Output, PING_TIMEOUT_MS, Sample, packet, ramp};

/// Run `iters` iterations of `case`.
pub fn measure(case: Case, iters: u64) -> Result<Sample, Error> {
    if case.len > CSP_CAN_MTU {
        return Err(Error::Argument("data longer than the 256-byte MTU"));
    }
    let (elapsed, output) = match case.op {
        Op::KissEncode => kiss_encode(&packet(case.len), iters),
        Op::CfpFragment => cfp_fragment(&packet(case.len), iters)?,
        Op::Crc32c => crc(&ramp(case.len), iters),
        Op::LoopbackPing => ping(case.len, iters)?,
    };
    Ok(Sample {
        iters,
        ns: u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX),
        output,
    })
}

/// KISS-encode `packet` `iters` times into one reused buffer.
fn kiss_encode(packet: &Packet, iters: u64) -> (Duration, Output) {
    let mut out = Vec::with_capacity(2 * (packet.data.len() + 8) + 3);
    let start = Instant::now();
    for _ in 0..iters {
        out.clear();
        kiss::encode(black_box(packet), &mut out);
        black_box(&out);
    }
    (start.elapsed(), Output::Kiss(out))
}

/// Fragment `packet` `iters` times into one reused frame list (next hop: its destination,
/// as libcsp's `csp_can_tx` picks it without a route MAC).
fn cfp_fragment(packet: &Packet, iters: u64) -> Result<(Duration, Output), Error> {
    let mut fragmenter = Fragmenter::new(0, CSP_CAN_MTU);
    let mut frames: Vec<CanFrame> = Vec::with_capacity(40);
    let mac = packet.header.dst;
    let start = Instant::now();
    for _ in 0..iters {
        frames.clear();
        fragmenter
            .fragment(black_box(packet), mac, &mut frames)
            .map_err(|e| Error::Ours {
                op: Op::CfpFragment.name(),
                detail: e.to_string(),
            })?;
        black_box(&frames);
    }
    Ok((start.elapsed(), Output::Cfp(frames)))
}

/// The CRC-32C of `data`, `iters` times.
fn crc(data: &[u8], iters: u64) -> (Duration, Output) {
    let mut last = 0;
    let start = Instant::now();
    for _ in 0..iters {
        last = crc32::crc32c(black_box(data));
        black_box(last);
    }
    (start.elapsed(), Output::Crc(last))
}

/// `iters` pings of `len` bytes from a node to its own address.
fn ping(len: usize, iters: u64) -> Result<(Duration, Output), Error> {
    let fail = |detail: String| Error::Ours {
        op: Op::LoopbackPing.name(),
        detail,
    };
    // No interface: a packet to the node's own address needs none (the loopback).
    let mut node = Node::new(NodeConfig::new("bench", NODE_ADDR), SimTime::ZERO);
    let mut client = Client::new();
    let template = Header::new(NODE_ADDR, NODE_ADDR, 0, 0);
    let timeout = Duration::from_millis(u64::from(PING_TIMEOUT_MS));
    let now = SimTime::ZERO;
    let start = Instant::now();
    for tag in 0..iters {
        // As csp_ping: a fresh buffer filled with 0, 1, 2, ...
        let data = ramp(black_box(len));
        client
            .request(
                &mut node,
                tag,
                template,
                NODE_ADDR,
                csp::service::PORT_PING,
                data,
                timeout,
                now,
            )
            .map_err(|e| fail(e.to_string()))?;
        let reply = node
            .poll_delivery()
            .ok_or_else(|| fail("no reply".to_owned()))?;
        let done = client
            .handle_reply(&mut node, &reply, now)
            .ok_or_else(|| fail(format!("reply {} matches no request", reply.header)))?;
        let echoed = done.reply.data.len() == len
            && done
                .reply
                .data
                .iter()
                .enumerate()
                .all(|(i, &b)| b == i as u8);
        if !echoed {
            return Err(fail("wrong echo".to_owned()));
        }
    }
    Ok((start.elapsed(), Output::PingAnswered))
}
