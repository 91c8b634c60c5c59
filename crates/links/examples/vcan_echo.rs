//! CSP ping over a real SocketCAN interface: two [`SocketCanLink`]s on one interface
//! play two CSP nodes.
//!
//! Node A (CSP address 16) fragments a ping (20-byte payload, to node 3 port 1) with
//! the CFP [`Fragmenter`] and sends the frames; node B (address 3) receives them from
//! the kernel, reassembles, and answers with the echo (3 -> 16); node A reassembles the
//! reply and checks it byte for byte. A third raw socket also injects a standard-id
//! frame and a remote frame, which both links must skip and count.
//!
//! ```text
//! cargo build -p m6p-links --features socketcan --example vcan_echo
//! tools/uml/run-in-uml.sh target/debug/examples/vcan_echo vcan0   # no SocketCAN on the host
//! target/debug/examples/vcan_echo vcan0                            # host with vcan0 up
//! ```
//!
//! Exit status 0 on success, 1 with a message otherwise. The integration test
//! `crates/links/tests/vcan_uml.rs` runs the same [`run`] inside a User-Mode Linux guest.

use std::error::Error;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use csp::cfp::{CanFrame, CfpId, Fragmenter, Reassembler};
use csp::{Header, Packet, SimTime};
use m6p_links::socketcan::{SocketCanLink, SocketCanStats};
use socketcan::{EmbeddedFrame, ExtendedId, StandardId};

/// CSP address of node A (the pinging client).
pub const NODE_A: u8 = 16;
/// CSP address of node B (the echo server).
pub const NODE_B: u8 = 3;
/// CSP ping service port.
pub const PING_PORT: u8 = 1;
/// Node A's (ephemeral) source port.
pub const CLIENT_PORT: u8 = 40;
/// Ping payload length.
pub const PAYLOAD_LEN: usize = 20;
/// Longest wait for any one node to finish.
pub const NODE_TIMEOUT: Duration = Duration::from_secs(10);

type BoxError = Box<dyn Error + Send + Sync>;

/// What one successful run saw.
#[derive(Debug)]
pub struct EchoReport {
    /// Interface used.
    pub ifname: String,
    /// Frames of the request (node A -> node B).
    pub request_frames: usize,
    /// Frames of the reply (node B -> node A).
    pub reply_frames: usize,
    /// Node A's link counters at the end.
    pub a: SocketCanStats,
    /// Node B's link counters at the end.
    pub b: SocketCanStats,
    /// Time from the first request frame sent to the reply reassembled.
    pub round_trip: Duration,
}

/// The ping payload: 20 distinct, non-trivial bytes (includes 0x00 and 0xFF).
pub fn ping_payload() -> Vec<u8> {
    let mut p: Vec<u8> = (0..PAYLOAD_LEN as u8)
        .map(|i| i.wrapping_mul(37).wrapping_add(0xC5))
        .collect();
    p[3] = 0x00;
    p[11] = 0xFF;
    p
}

fn now(start: Instant) -> SimTime {
    SimTime::from_ns(u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX))
}

/// Check the fragmenter's frames against the CFP layout spelled out by hand.
fn check_layout(
    frames: &[CanFrame],
    header: &Header,
    payload: &[u8],
    ident: u16,
) -> Result<(), BoxError> {
    // BEGIN carries 2 data bytes, then 8 per MORE frame.
    let expected_count = 1 + (payload.len() - 2).div_ceil(8);
    if frames.len() != expected_count {
        return Err(format!(
            "fragmenter made {} frames, expected {expected_count}",
            frames.len()
        )
        .into());
    }
    for (i, frame) in frames.iter().enumerate() {
        let remain = (expected_count - 1 - i) as u32;
        let kind = u32::from(i != 0);
        let id = u32::from(NODE_A) << 24
            | u32::from(NODE_B) << 19
            | kind << 18
            | remain << 10
            | u32::from(ident);
        if frame.id != id {
            return Err(format!("frame {i}: id {:#010x}, expected {id:#010x}", frame.id).into());
        }
        let mut data = Vec::new();
        if i == 0 {
            data.extend_from_slice(&header.to_word().to_be_bytes());
            data.extend_from_slice(&(payload.len() as u16).to_be_bytes());
            data.extend_from_slice(&payload[..2]);
        } else {
            let start = 2 + (i - 1) * 8;
            data.extend_from_slice(&payload[start..(start + 8).min(payload.len())]);
        }
        if frame.data() != data.as_slice() {
            return Err(format!(
                "frame {i}: data {:02x?}, expected {data:02x?}",
                frame.data()
            )
            .into());
        }
    }
    Ok(())
}

/// Receive frames on `link` until one CSP packet addressed (CFP dst) to `me` is complete.
async fn recv_packet(
    link: &mut SocketCanLink,
    me: u8,
    start: Instant,
) -> Result<(Packet, usize), BoxError> {
    let mut reasm = Reassembler::default();
    let mut frames = 0;
    loop {
        let frame = link.recv().await?;
        let cfp = CfpId::from_can_id(frame.id);
        if cfp.dst != me {
            continue;
        }
        frames += 1;
        match reasm.handle(&frame, now(start)) {
            Some(Ok(packet)) => return Ok((packet, frames)),
            Some(Err(drop)) => {
                return Err(format!("node {me}: CFP reassembly dropped a frame: {drop}").into());
            }
            None => {}
        }
    }
}

async fn send_all(link: &SocketCanLink, frames: &[CanFrame]) -> Result<(), BoxError> {
    for frame in frames {
        link.send(frame).await?;
    }
    Ok(())
}

/// Node B: answer one ping with its echo.
async fn echo_server(
    mut link: SocketCanLink,
    start: Instant,
) -> Result<(SocketCanLink, usize), BoxError> {
    let (request, _) = recv_packet(&mut link, NODE_B, start).await?;
    let h = request.header;
    if h.dst != NODE_B || h.dport != PING_PORT {
        return Err(format!("node B: unexpected packet {h}").into());
    }
    let reply = Packet::new(h.reply(NODE_B), request.data);
    let mut frames = Vec::new();
    Fragmenter::new(700, 256).fragment(&reply, reply.header.dst, &mut frames)?;
    send_all(&link, &frames).await?;
    Ok((link, frames.len()))
}

/// Node A: send the ping and wait for the echo; returns the reply and the frame count.
async fn ping_client(
    mut link: SocketCanLink,
    request: Packet,
    frames: Vec<CanFrame>,
    start: Instant,
) -> Result<(SocketCanLink, Packet, usize), BoxError> {
    send_all(&link, &frames).await?;
    let (reply, n) = recv_packet(&mut link, NODE_A, start).await?;
    let expect_header = request.header.reply(NODE_B);
    if reply.header != expect_header {
        return Err(format!(
            "node A: reply header {} != expected {expect_header}",
            reply.header
        )
        .into());
    }
    if reply.data != request.data {
        return Err(format!(
            "node A: echo {:02x?} != sent {:02x?}",
            reply.data, request.data
        )
        .into());
    }
    Ok((link, reply, n))
}

/// Inject frames CFP does not use: a standard-id data frame and an extended remote frame.
async fn inject_noise(ifname: &str) -> Result<(), BoxError> {
    let sock = socketcan::tokio::CanSocket::open(ifname)
        .map_err(|e| format!("noise socket on `{ifname}`: {e}"))?;
    let std_id = StandardId::new(0x123).ok_or("standard id")?;
    let standard = socketcan::CanDataFrame::new(std_id, &[0xAA, 0x55]).ok_or("standard frame")?;
    sock.write_frame(standard.into()).await?;
    let ext_id = ExtendedId::new(u32::from(NODE_B) << 19).ok_or("extended id")?;
    let remote = socketcan::CanRemoteFrame::new_remote(ext_id, 4).ok_or("remote frame")?;
    sock.write_frame(remote.into()).await?;
    Ok(())
}

/// Run the ping/echo on `ifname`; `Err` describes the first mismatch.
pub async fn run(ifname: &str) -> Result<EchoReport, BoxError> {
    let a = SocketCanLink::open(ifname)?;
    let b = SocketCanLink::open(ifname)?;
    inject_noise(ifname).await?;

    let payload = ping_payload();
    let request = Packet::new(
        Header::new(NODE_A, NODE_B, PING_PORT, CLIENT_PORT),
        payload.clone(),
    );
    let mut frag = Fragmenter::new(42, 256);
    let mut frames = Vec::new();
    let ident = frag.fragment(&request, NODE_B, &mut frames)?;
    check_layout(&frames, &request.header, &payload, ident)?;
    let request_frames = frames.len();

    let start = Instant::now();
    let client = tokio::time::timeout(NODE_TIMEOUT, ping_client(a, request, frames, start));
    let server = tokio::time::timeout(NODE_TIMEOUT, echo_server(b, start));
    let (client, server) = tokio::join!(client, server);
    let (b, reply_frames) = server.map_err(|_| "node B: timed out waiting for the ping")??;
    let (a, _reply, reply_frames_seen) =
        client.map_err(|_| "node A: timed out waiting for the echo")??;
    let round_trip = start.elapsed();

    let (sa, sb) = (a.stats(), b.stats());
    if reply_frames_seen != reply_frames {
        return Err(format!(
            "node A saw {reply_frames_seen} reply frames, node B sent {reply_frames}"
        )
        .into());
    }
    for (name, s, sent, received) in [
        ("A", sa, request_frames, reply_frames),
        ("B", sb, reply_frames, request_frames),
    ] {
        if s.frames_out != sent as u64 || s.frames_in != received as u64 {
            return Err(
                format!("node {name}: stats {s:?}, expected {sent} out / {received} in").into(),
            );
        }
        if s.skipped_standard != 1 || s.skipped_remote != 1 || s.skipped_error != 0 {
            return Err(format!(
                "node {name}: expected 1 standard + 1 remote frame skipped, stats {s:?}"
            )
            .into());
        }
    }
    Ok(EchoReport {
        ifname: ifname.to_owned(),
        request_frames,
        reply_frames,
        a: sa,
        b: sb,
        round_trip,
    })
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> ExitCode {
    let ifname = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "vcan0".to_owned());
    match run(&ifname).await {
        Ok(r) => {
            println!(
                "vcan_echo: OK on {}: ping {} -> {}:{} ({} B, {} frames), echo back ({} frames) in {:?}; A {:?}; B {:?}",
                r.ifname,
                NODE_A,
                NODE_B,
                PING_PORT,
                PAYLOAD_LEN,
                r.request_frames,
                r.reply_frames,
                r.round_trip,
                r.a,
                r.b
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("vcan_echo: FAILED on {ifname}: {e}");
            ExitCode::FAILURE
        }
    }
}
