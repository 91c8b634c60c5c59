//! `m6p-twin gs`: a small ground-station client that joins a running twin over KISS/TCP
//! (as node 17 by default: 16 is the scenario's own GS16) and sends service requests, printing round-trip times. It is
//! the first piece of the ground console.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use csp::kiss::{self, Decoder, DecoderConfig, KissEvent};
use csp::service::{CMP_IDENT, CMP_IDENT_LEN, CMP_REQUEST, PORT_CMP, PORT_PING, PORT_UPTIME};
use csp::{Header, Packet};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// The twin closed the ground station's connection: nothing more can be asked over it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the twin closed the connection")]
pub struct Closed;

/// A ground node on a KISS/TCP connection.
#[derive(Debug)]
pub struct GsClient {
    stream: TcpStream,
    decoder: Decoder,
    addr: u8,
    next_port: u8,
    pending: Vec<Packet>,
}

impl GsClient {
    /// Connect to a twin's KISS server as node `addr`.
    pub async fn connect(server: SocketAddr, addr: u8) -> anyhow::Result<Self> {
        let stream = TcpStream::connect(server)
            .await
            .with_context(|| format!("connecting to {server}"))?;
        let _ = stream.set_nodelay(true);
        Ok(GsClient {
            stream,
            decoder: Decoder::new(DecoderConfig::default()),
            addr,
            next_port: 32,
            pending: Vec::new(),
        })
    }

    /// Send `data` to `dst:dport` and wait up to `timeout` for the reply; `None` on timeout.
    pub async fn request(
        &mut self,
        dst: u8,
        dport: u8,
        data: Vec<u8>,
        timeout: Duration,
    ) -> anyhow::Result<Option<(Packet, Duration)>> {
        let sport = self.next_port;
        self.next_port = if sport >= 63 { 32 } else { sport + 1 };
        // A late reply to an earlier request from this port is not this one's.
        self.pending.retain(|p| p.header.dport != sport);
        let packet = Packet::new(Header::new(self.addr, dst, dport, sport), data);
        let mut wire = Vec::new();
        kiss::encode(&packet, &mut wire);
        let start = Instant::now();
        self.stream
            .write_all(&wire)
            .await
            .context("sending the request")?;
        let deadline = tokio::time::Instant::now() + timeout;
        let mut buf = [0u8; 2048];
        let mut events = Vec::new();
        loop {
            if let Some(i) = self.pending.iter().position(|p| {
                p.header.dport == sport && p.header.src == dst && p.header.sport == dport
            }) {
                return Ok(Some((self.pending.remove(i), start.elapsed())));
            }
            let n = match tokio::time::timeout_at(deadline, self.stream.read(&mut buf)).await {
                Err(_) => return Ok(None),
                Ok(Ok(0)) => return Err(Closed.into()),
                Ok(Ok(n)) => n,
                Ok(Err(e)) => return Err(e).context("reading the reply"),
            };
            self.decoder
                .push(buf.get(..n).unwrap_or_default(), &mut events);
            for ev in events.drain(..) {
                if let KissEvent::Packet(p) = ev {
                    self.pending.push(p);
                }
            }
            // Keep only a bounded backlog of unmatched packets (late replies).
            if self.pending.len() > 64 {
                self.pending.drain(..self.pending.len() - 64);
            }
        }
    }
}

/// `gs ping`: `count` pings of `size` bytes, one per `interval`; prints each and a summary.
pub async fn ping(
    gs: &mut GsClient,
    node: u8,
    count: u32,
    size: usize,
    interval: Duration,
    timeout: Duration,
) -> anyhow::Result<bool> {
    if size > csp::kiss::KISS_MTU {
        bail!(
            "a ping of {size} bytes does not fit a CSP packet: at most {} bytes",
            csp::kiss::KISS_MTU
        );
    }
    let payload = crate::ground::ping_payload(size);
    let mut rtts = Vec::new();
    for seq in 1..=count {
        match gs
            .request(node, PORT_PING, payload.clone(), timeout)
            .await?
        {
            Some((reply, rtt)) if reply.data == payload => {
                println!(
                    "reply from {node}: seq={seq} size={size} time={:.3} ms",
                    rtt.as_secs_f64() * 1e3
                );
                rtts.push(rtt);
            }
            Some((reply, _)) => println!(
                "reply from {node}: seq={seq} WRONG ECHO ({} bytes)",
                reply.data.len()
            ),
            None => println!(
                "no reply from {node}: seq={seq} (timeout {:.1} s)",
                timeout.as_secs_f64()
            ),
        }
        if seq < count {
            tokio::time::sleep(interval).await;
        }
    }
    println!("{}", ping_summary(node, count, &rtts));
    Ok(!rtts.is_empty())
}

/// The last line of `gs ping`: how many of the `sent` pings were answered and, when any
/// were, the median round-trip time of those (an empty set has no median: nothing
/// answered says so instead).
pub fn ping_summary(node: u8, sent: u32, rtts: &[Duration]) -> String {
    let mut sorted = rtts.to_vec();
    sorted.sort();
    match sorted.get(sorted.len() / 2) {
        Some(median) => format!(
            "--- node {node}: {sent} sent, {} answered, median {:.3} ms",
            sorted.len(),
            median.as_secs_f64() * 1e3
        ),
        None => format!("--- node {node}: 0 of {sent} answered, no round-trip time"),
    }
}

/// `gs uptime`.
pub async fn uptime(
    gs: &mut GsClient,
    node: u8,
    timeout: Duration,
    icd_ms: bool,
) -> anyhow::Result<bool> {
    match gs.request(node, PORT_UPTIME, Vec::new(), timeout).await? {
        Some((reply, rtt)) => {
            let Ok(b) = <[u8; 4]>::try_from(reply.data.as_slice()) else {
                println!(
                    "node {node}: malformed uptime reply of {} bytes",
                    reply.data.len()
                );
                return Ok(false);
            };
            if icd_ms {
                println!(
                    "node {node}: uptime {} ms (u32 LE, ICD reading) ({:.3} ms)",
                    u32::from_le_bytes(b),
                    rtt.as_secs_f64() * 1e3
                );
            } else {
                println!(
                    "node {node}: uptime {} s ({:.3} ms)",
                    u32::from_be_bytes(b),
                    rtt.as_secs_f64() * 1e3
                );
            }
            Ok(true)
        }
        None => {
            println!(
                "no reply from {node} (timeout {:.1} s)",
                timeout.as_secs_f64()
            );
            Ok(false)
        }
    }
}

/// `gs ident`: CMP ident (hostname, model, revision, date, time).
pub async fn ident(gs: &mut GsClient, node: u8, timeout: Duration) -> anyhow::Result<bool> {
    match gs
        .request(node, PORT_CMP, vec![CMP_REQUEST, CMP_IDENT], timeout)
        .await?
    {
        Some((reply, rtt)) if reply.data.len() == CMP_IDENT_LEN => {
            let field = |a: usize, b: usize| {
                let f = reply.data.get(a..b).unwrap_or_default();
                let end = f.iter().position(|&c| c == 0).unwrap_or(f.len());
                String::from_utf8_lossy(&f[..end]).into_owned()
            };
            println!(
                "node {node}: hostname {:?} model {:?} revision {:?} built {} {} ({:.3} ms)",
                field(2, 22),
                field(22, 52),
                field(52, 72),
                field(72, 84),
                field(84, 93),
                rtt.as_secs_f64() * 1e3
            );
            Ok(true)
        }
        Some((reply, _)) => {
            println!(
                "node {node}: malformed ident reply of {} bytes",
                reply.data.len()
            );
            Ok(false)
        }
        None => {
            println!(
                "no reply from {node} (timeout {:.1} s)",
                timeout.as_secs_f64()
            );
            Ok(false)
        }
    }
}

fn no_reply(node: u8, timeout: Duration) -> anyhow::Result<bool> {
    println!(
        "no reply from {node} (timeout {:.1} s)",
        timeout.as_secs_f64()
    );
    Ok(false)
}

/// `gs raw`: any request; prints the reply as [`raw_reply`] reads it.
pub async fn raw(
    gs: &mut GsClient,
    node: u8,
    port: u8,
    data: Vec<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    match gs.request(node, port, data, timeout).await? {
        Some((reply, rtt)) => {
            print!(
                "{}",
                raw_reply(&reply.header, &reply.data, rtt.as_secs_f64() * 1e3).text
            );
            Ok(true)
        }
        None => no_reply(node, timeout),
    }
}

/// A reply to `gs raw` (`header` as it came, from the port the request went to), `ms`
/// after the request: decoded as a by-name ICD command's reply ([`show_reply`]) when it
/// comes from an ICD port (the default ports) with a command id of that port's table,
/// else its bytes in hex (judged [`ReplyVerdict::Ok`]: there is nothing to check it by).
pub fn raw_reply(header: &csp::Header, data: &[u8], ms: f64) -> Shown {
    let map = crate::icd::IcdMap::defaults();
    if let Some(c) = map.classify(header, data)
        && c.direction == crate::icd::Direction::Reply
        && let Some(d) = map.decode(header, data)
    {
        return show_reply(&d, c.command, header.src, data, ms);
    }
    Shown {
        text: format!(
            "{}:{} replied {} ({ms:.3} ms)\n",
            header.src,
            header.sport,
            hex::encode(data)
        ),
        verdict: ReplyVerdict::Ok,
    }
}

/// What a reply said, as `gs` judges it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyVerdict {
    /// Success, and the reply fits the ICD's layout.
    Ok,
    /// The node answered with a failure result.
    Refused,
    /// Success, but the reply's length does not fit the ICD's layout.
    Misfit,
}

/// A reply as `gs` prints it: its lines and its verdict.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Shown {
    /// The lines, each ending in a newline.
    pub text: String,
    /// What the reply said.
    pub verdict: ReplyVerdict,
}

/// The line `gs` prints for a refusal of `name` (`PC.SETUP`) by node `src` with result
/// `result`, `ms` after the request: with the node's `reason` when it told it (the PC's WHY,
/// the twin's own command), else where the reason is to be found.
pub fn refused_line(name: &str, src: u8, result: u8, reason: Option<&str>, ms: f64) -> String {
    match reason {
        Some(why) => format!("{name} from {src}: refused: {why} (result {result}) ({ms:.3} ms)\n"),
        None => format!(
            "{name} from {src}: refused (result {result}; the reason is in the run log, `/log` of the recording) ({ms:.3} ms)\n"
        ),
    }
}

/// A reply the ICD decoded (`d`, of command `cmd` from node `src`; `data` its bytes from the
/// command id on), as `gs` prints it: a head line (`PC.TMPC from 6: ok, 89 bytes (1.234
/// ms)`), then one line per field with the ICD's name, the value, its unit and value name;
/// or the refusal ([`refused_line`], without the reason).
pub fn show_reply(
    d: &crate::icd::DecodedPacket,
    cmd: &csp::icd::Command,
    src: u8,
    data: &[u8],
    ms: f64,
) -> Shown {
    use std::fmt::Write as _;
    let mut s = String::new();
    let name = format!("{}.{}", d.node, cmd.name);
    if d.result != Some(csp::reqrep::RESULT_SUCCESS) {
        return Shown {
            text: refused_line(&name, src, d.result.unwrap_or(0), None, ms),
            verdict: ReplyVerdict::Refused,
        };
    }
    let _ = writeln!(
        s,
        "{name} from {src}: ok, {} bytes ({ms:.3} ms)",
        data.len().saturating_sub(2)
    );
    for f in &d.fields {
        let _ = writeln!(s, "  {:<36} {}", f.path, f.show());
    }
    if let Some(t) = &d.tail {
        let tail = cmd
            .reply
            .parts()
            .and_then(|p| p.1)
            .map_or("(tail)", |t| t.name);
        if t.iter().all(|b| (0x20..0x7f).contains(b)) {
            let _ = writeln!(s, "  {tail:<36} {:?}", String::from_utf8_lossy(t));
        } else {
            let _ = writeln!(s, "  {tail:<36} {} ({} bytes)", hex::encode(t), t.len());
        }
    }
    if d.fields.is_empty() && d.tail.is_none() && data.len() > 2 {
        let _ = writeln!(s, "  data {}", hex::encode(&data[2..]));
    }
    if !d.fits {
        s.push_str("  (the reply's length does not fit the ICD's layout)\n");
        return Shown {
            text: s,
            verdict: ReplyVerdict::Misfit,
        };
    }
    Shown {
        text: s,
        verdict: ReplyVerdict::Ok,
    }
}

/// `gs setup|status|abort`: a request to the PC's session control port (6:10), its reply
/// printed as the same command by name prints it ([`show_reply`]), a refusal with the PC's
/// reason. Succeeds when the PC answers with result 1.
pub async fn pc_request(
    gs: &mut GsClient,
    request: Vec<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    use nodes_pc::wire::{ICD_CONTROL, PORT_CONTROL};
    let id = request.first().copied().unwrap_or(0);
    let Some(cmd) = ICD_CONTROL.command(id) else {
        bail!("the PC's control port has no command {id}");
    };
    let to = Target {
        node: "PC",
        addr: platform::addr::PC,
        port: PORT_CONTROL,
        icd_port: PORT_CONTROL,
    };
    send_and_show(gs, to, cmd, request, timeout).await
}

/// Where a request by name goes: the ICD's node name, its address, the port it is sent to
/// and the port the ICD lists the command on.
#[derive(Debug, Clone, Copy)]
struct Target<'a> {
    node: &'a str,
    addr: u8,
    port: u8,
    icd_port: u8,
}

/// Send `request` (command `cmd`) to `to` and print the reply decoded ([`show_reply`]); a
/// PC's refusal with the reason its WHY gives ([`pc_reason`]). Succeeds when the node
/// answers with result 1.
async fn send_and_show(
    gs: &mut GsClient,
    to: Target<'_>,
    cmd: &'static csp::icd::Command,
    request: Vec<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    let Some((reply, rtt)) = gs.request(to.addr, to.port, request, timeout).await? else {
        return no_reply(to.addr, timeout);
    };
    let ms = rtt.as_secs_f64() * 1e3;
    let map = crate::icd::IcdMap::defaults();
    let mut h = reply.header;
    // Read it as a reply from the ICD's default port, wherever the node answered from.
    h.sport = to.icd_port;
    h.dport = h.dport.max(csp::header::EPHEMERAL_PORT_MIN);
    let body = &reply.data[..];
    match map.decode(&h, body) {
        Some(d) if d.command == cmd.name => {
            if d.result != Some(csp::reqrep::RESULT_SUCCESS)
                && to.addr == platform::addr::PC
                && let Some(why) = pc_reason(gs, to, cmd.id, timeout).await?
            {
                let name = format!("{}.{}", d.node, cmd.name);
                let result = d.result.unwrap_or(0);
                print!("{}", refused_line(&name, to.addr, result, Some(&why), ms));
                return Ok(false);
            }
            let shown = show_reply(&d, cmd, to.addr, body, ms);
            print!("{}", shown.text);
            Ok(shown.verdict == ReplyVerdict::Ok)
        }
        _ => {
            println!(
                "{}.{}: unexpected reply {}",
                to.node,
                cmd.name,
                hex::encode(body)
            );
            Ok(false)
        }
    }
}

/// Why the PC at `to` refused this client's request `command` on `to.port`, as its WHY (the
/// twin's own command, on the control port) tells it, from this client's address. `None`
/// when the PC does not answer WHY (a real PC has no such command) or its last refusal of
/// this address is another request.
async fn pc_reason(
    gs: &mut GsClient,
    to: Target<'_>,
    command: u8,
    timeout: Duration,
) -> anyhow::Result<Option<String>> {
    use nodes_pc::wire::{PORT_CONTROL, RefusalCode, Why, cmd};
    // WHY is on the control port: the one the request went to if it went there (`--port`
    // moves it), else the ICD's.
    let control = if to.icd_port == PORT_CONTROL {
        to.port
    } else {
        PORT_CONTROL
    };
    let Some((reply, _)) = gs
        .request(to.addr, control, vec![cmd::WHY], timeout)
        .await?
    else {
        return Ok(None);
    };
    let [cmd::WHY, csp::reqrep::RESULT_SUCCESS, data @ ..] = reply.data.as_slice() else {
        return Ok(None);
    };
    Ok(Why::parse(data)
        .ok()
        .filter(|w| w.code != RefusalCode::None && (w.port, w.command) == (to.port, command))
        .map(|w| w.reason))
}

/// Arguments `name=value` as the ICD's encoder takes them: a number where the text is one,
/// an array for `a,b,c`, else the text (a value's name, a duration, text).
pub fn parse_args(
    words: &[String],
) -> anyhow::Result<std::collections::BTreeMap<String, serde_json::Value>> {
    fn value(s: &str) -> serde_json::Value {
        if let Ok(i) = s.parse::<i64>() {
            return i.into();
        }
        match s.parse::<f64>() {
            Ok(x) if x.is_finite() => {
                serde_json::Number::from_f64(x).map_or_else(|| s.into(), serde_json::Value::Number)
            }
            _ => s.into(),
        }
    }
    let mut out = std::collections::BTreeMap::new();
    for w in words {
        let Some((k, v)) = w.split_once('=') else {
            bail!("`{w}` is not NAME=VALUE (`m6p-twin icd NODE` lists a command's fields)");
        };
        let v = if v.contains(',') {
            serde_json::Value::Array(v.split(',').map(|x| value(x.trim())).collect())
        } else {
            value(v)
        };
        out.insert(k.to_owned(), v);
    }
    Ok(out)
}

/// The CSP address of a node name as `gs` takes it: `FC`, `COMM2`, `PL12`, or a number.
fn node_addr(name: &str, icd_node: &crate::icd::NodeIcd) -> Option<u8> {
    if let Ok(a) = name.parse::<u8>() {
        return Some(a);
    }
    let n = name.to_ascii_uppercase();
    if let Some(rest) = n.strip_prefix("PL") {
        return rest.parse().ok();
    }
    match n.as_str() {
        "COMM2" => Some(2),
        _ => icd_node
            .addrs
            .first()
            .copied()
            .filter(|_| icd_node.addrs.len() == 1 || n == "COMM" || n == "COMM1"),
    }
}

/// `gs NODE COMMAND [NAME=VALUE ...]`: any ICD command by name (`fc tmatp`, `pc setup
/// session_id=1 timestamp=now duration_s=10m max_packets=0 poll_frame_size=200`), its
/// arguments checked against the ICD before anything is sent, and the reply decoded with
/// units and value names; a PC's refusal with the PC's reason. `port` overrides the ICD's
/// default port. Succeeds when the node answers with result 1.
pub async fn icd_command(
    gs: &mut GsClient,
    words: &[String],
    port: Option<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    let [node, command, args @ ..] = words else {
        bail!(
            "usage: m6p-twin gs --connect ADDR NODE COMMAND [NAME=VALUE ...] (`m6p-twin icd` lists them)"
        );
    };
    let (icd_node, icd_port, cmd) = crate::icd::find_command(&format!("{node}.{command}"))?;
    let Some(dst) = node_addr(node, &icd_node) else {
        bail!(
            "which {} is `{node}`? Name one: {}",
            icd_node.name,
            icd_node
                .addrs
                .iter()
                .map(u8::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    if !icd_node.addrs.contains(&dst) {
        bail!(
            "{} {} goes to the {}, not to {dst}",
            icd_node.name,
            cmd.name,
            icd_node.name
        );
    }
    let args = parse_args(args)?;
    let data = crate::icd::encode_args(cmd, &args).map_err(|(field, m)| {
        if field.is_empty() {
            anyhow::anyhow!("{}: {m}", cmd.name)
        } else {
            anyhow::anyhow!("{}.{field}: {m}", cmd.name)
        }
    })?;
    let mut request = vec![cmd.id];
    request.extend(data);
    let to = Target {
        node: icd_node.name,
        addr: dst,
        port: port.unwrap_or(icd_port.port),
        icd_port: icd_port.port,
    };
    send_and_show(gs, to, cmd, request, timeout).await
}

/// Send one request to a run's control channel (`run --control`) and print its reply:
/// whether it was taken.
pub fn control(
    addr: SocketAddr,
    req: &serde_json::Value,
    timeout: Duration,
) -> anyhow::Result<bool> {
    use std::io::{BufRead as _, Write as _};
    let stream = std::net::TcpStream::connect_timeout(&addr, timeout)
        .with_context(|| format!("connecting to the control channel on {addr}"))?;
    stream.set_read_timeout(Some(timeout))?;
    let mut w = stream.try_clone()?;
    writeln!(w, "{req}")?;
    let mut line = String::new();
    std::io::BufReader::new(stream)
        .read_line(&mut line)
        .with_context(|| format!("reading the reply from {addr} (waited {timeout:?})"))?;
    let reply: serde_json::Value = serde_json::from_str(line.trim())
        .with_context(|| format!("the reply is not JSON: {line:?}"))?;
    let secs = |k: &str| {
        reply[k]
            .as_u64()
            .map(|ns| format!("{:.3} s", ns as f64 * 1e-9))
    };
    if reply["ok"] != true {
        eprintln!(
            "refused: {}",
            reply["error"].as_str().unwrap_or("(no reason given)")
        );
        return Ok(false);
    }
    let now = secs("t_ns").unwrap_or_default();
    match req["op"].as_str() {
        Some("fault") => {
            let until = secs("until_ns").map_or(String::new(), |u| format!(" until {u}"));
            println!(
                "{} (id {}): from {}{until} (the run is at {now})",
                reply["what"].as_str().unwrap_or(""),
                reply["id"],
                secs("at_ns").unwrap_or_default(),
            );
        }
        Some("clear") => println!(
            "control[{}] cleared at {now}: {}",
            reply["id"],
            match reply["was"].as_str() {
                Some("active") => "lifted",
                Some("pending") => "taken off before it started",
                _ => "it was over already",
            }
        ),
        Some("snapshot") => println!(
            "snapshot at {now}: {} in the run's --snapshot-dir, when the run settles there",
            reply["snapshot"].as_str().unwrap_or("")
        ),
        _ => println!("{now}"),
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_ping_summary_has_a_median_only_of_answers() {
        assert_eq!(
            ping_summary(8, 5, &[]),
            "--- node 8: 0 of 5 answered, no round-trip time"
        );
        let ms = Duration::from_millis;
        assert_eq!(
            ping_summary(3, 4, &[ms(40), ms(10), ms(30)]),
            "--- node 3: 4 sent, 3 answered, median 30.000 ms"
        );
    }

    /// The reply to `raw 6 12 01` (PC telemetry port, TMPC), all fields zero but the
    /// command and result bytes, from the ICD's own layout.
    fn tmpc_reply() -> (csp::Header, Vec<u8>) {
        let (_, port, cmd) = crate::icd::find_command("PC.TMPC").unwrap();
        let (len, _) = cmd.reply.bounds();
        let mut data = vec![cmd.id, csp::reqrep::RESULT_SUCCESS];
        data.resize(2 + len, 0);
        (Header::new(6, 17, 40, port.port), data)
    }

    #[test]
    fn raw_decodes_a_reply_the_icd_knows_as_a_command_by_name_does() {
        let (header, data) = tmpc_reply();
        assert_eq!(header.sport, 12);
        let Shown { text, verdict } = raw_reply(&header, &data, 1.5);
        assert_eq!(verdict, ReplyVerdict::Ok);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            format!("PC.TMPC from 6: ok, {} bytes (1.500 ms)", data.len() - 2)
        );
        // One line per field, with the ICD's name, the value and its unit or value name.
        let d = crate::icd::IcdMap::defaults()
            .decode(&header, &data)
            .unwrap();
        assert!(!d.fields.is_empty());
        assert_eq!(lines.len(), 1 + d.fields.len(), "{text}");
        for (line, f) in lines[1..].iter().zip(&d.fields) {
            assert_eq!(line.split_whitespace().next(), Some(f.path.as_str()));
        }
        assert!(text.contains("slots[0].state                       0 (NOT ACTIVE)"));
        assert!(text.contains("sband_queue_bytes                    0 B"));
        assert!(!text.contains("replied"), "{text}");
        // The same text as the by-name command prints.
        let (_, _, cmd) = crate::icd::find_command("PC.TMPC").unwrap();
        assert_eq!(
            show_reply(&d, cmd, 6, &data, 1.5),
            Shown {
                text,
                verdict: ReplyVerdict::Ok
            }
        );
    }

    /// A refusal with the node's reason names it; without one it says where it is.
    #[test]
    fn a_refusal_line_has_the_reason_when_the_node_told_it() {
        assert_eq!(
            refused_line("PC.SETUP", 6, 0, Some("window overlaps session 2"), 1.5),
            "PC.SETUP from 6: refused: window overlaps session 2 (result 0) (1.500 ms)\n"
        );
        assert_eq!(
            refused_line("FC.TMPERSET", 3, 0, None, 2.0),
            "FC.TMPERSET from 3: refused (result 0; the reason is in the run log, `/log` of \
             the recording) (2.000 ms)\n"
        );
    }

    #[test]
    fn raw_falls_back_to_hex_where_the_icd_knows_nothing() {
        // A ping's echo (port 1 is no ICD port).
        let shown = raw_reply(&Header::new(3, 17, 40, 1), &[1, 2], 2.0);
        assert_eq!(
            (shown.text.as_str(), shown.verdict),
            ("3:1 replied 0102 (2.000 ms)\n", ReplyVerdict::Ok)
        );
        // An ICD port, but a command id its table does not have.
        let text = raw_reply(&Header::new(6, 17, 40, 12), &[0xee, 1], 2.0).text;
        assert_eq!(text, "6:12 replied ee01 (2.000 ms)\n");
        // A refusal is read as one.
        let Shown { text, verdict } = raw_reply(&Header::new(6, 17, 40, 12), &[1, 0], 2.0);
        assert_eq!(verdict, ReplyVerdict::Refused);
        assert!(
            text.starts_with("PC.TMPC from 6: refused (result 0"),
            "{text}"
        );
    }
}
