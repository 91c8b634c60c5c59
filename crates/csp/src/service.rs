//! The CSP service handler on ports 0-6 (libcsp 1.4 `src/csp_service_handler.c`).
//!
//! | port | service | reply |
//! |---|---|---|
//! | 0 | CMP (ident, clock) | `ff code ...`; unknown codes or type != 0 get no reply |
//! | 1 | ping | the request echoed |
//! | 2 | ps | ASCII text, at most 196 bytes |
//! | 3 | memfree | u32 big-endian |
//! | 4 | reboot | none; magic `80 07 80 07` reboots the node (inside the twin only) |
//! | 5 | buf_free | u32 big-endian count of free buffers |
//! | 6 | uptime | u32 big-endian seconds (libcsp), or u32 little-endian ms (ICD option) |
//!
//! The uptime format follows INTERPRETATION.md section 3: libcsp's by default, the ICD's
//! reading as an option.

use crate::SimTime;

/// CMP port.
pub const PORT_CMP: u8 = 0;
/// Ping port.
pub const PORT_PING: u8 = 1;
/// Process list port.
pub const PORT_PS: u8 = 2;
/// Free memory port.
pub const PORT_MEMFREE: u8 = 3;
/// Reboot port.
pub const PORT_REBOOT: u8 = 4;
/// Free buffers port.
pub const PORT_BUF_FREE: u8 = 5;
/// Uptime port.
pub const PORT_UPTIME: u8 = 6;
/// Highest service port.
pub const MAX_SERVICE_PORT: u8 = 6;

/// Whether a payload may use service `port` of a platform node: ICD 4.1 stars the service
/// handler's ping and uptime only.
pub fn open_to_payloads(port: u8) -> bool {
    matches!(port, PORT_PING | PORT_UPTIME)
}

/// The reason a platform node drops a payload's request for service `port` (the node's
/// drop counter, by service).
pub fn payload_refusal(port: u8) -> crate::drop::DropReason {
    use crate::drop::DropReason;
    match port {
        PORT_CMP => DropReason::PayloadCmp,
        PORT_PS => DropReason::PayloadPs,
        PORT_MEMFREE => DropReason::PayloadMemfree,
        PORT_REBOOT => DropReason::PayloadReboot,
        PORT_BUF_FREE => DropReason::PayloadBufFree,
        _ => DropReason::PayloadService,
    }
}

/// CMP message type of a request.
pub const CMP_REQUEST: u8 = 0x00;
/// CMP message type of a reply.
pub const CMP_REPLY: u8 = 0xff;
/// CMP code IDENT.
pub const CMP_IDENT: u8 = 1;
/// CMP code CLOCK.
pub const CMP_CLOCK: u8 = 6;
/// Length of a CMP IDENT reply (`ff 01` + 20 + 30 + 20 + 12 + 9).
pub const CMP_IDENT_LEN: usize = 93;
/// The reboot magic (`CSP_REBOOT_MAGIC`).
pub const REBOOT_MAGIC: u32 = 0x8007_8007;
/// Largest ps reply (`CSP_RPS_MTU`).
pub const PS_MTU: usize = 196;

/// How a node answers the uptime service.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UptimeFormat {
    /// libcsp 1.4: u32 big-endian seconds.
    #[default]
    LibcspSecondsBe,
    /// The ICD's table: u32 little-endian milliseconds.
    IcdMillisLe,
}

/// Static answers of a node's service handler.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceConfig {
    /// CMP ident hostname (20 bytes on the wire).
    pub hostname: String,
    /// CMP ident model (30 bytes).
    pub model: String,
    /// CMP ident revision (20 bytes).
    pub revision: String,
    /// CMP ident build date (12 bytes, `__DATE__` style).
    pub date: String,
    /// CMP ident build time (9 bytes, `__TIME__` style).
    pub time: String,
    /// The ps reply text.
    pub ps_text: String,
    /// The memfree reply, bytes.
    pub memfree_bytes: u32,
    /// The buf_free reply, a count of buffers.
    pub buffers_free: u32,
    /// The uptime format.
    pub uptime: UptimeFormat,
}

impl ServiceConfig {
    /// Defaults for a node named `hostname`.
    pub fn named(hostname: &str) -> Self {
        ServiceConfig {
            hostname: hostname.to_owned(),
            model: "M6P twin".to_owned(),
            revision: concat!("m6p-twin ", env!("CARGO_PKG_VERSION")).to_owned(),
            date: "Nov 21 2026".to_owned(),
            time: "00:00:00".to_owned(),
            ps_text: format!("{hostname}: csp-router csp-service app"),
            memfree_bytes: 128 * 1024,
            buffers_free: 10,
            uptime: UptimeFormat::default(),
        }
    }
}

/// What the service handler asks the node to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServiceAction {
    /// Send these reply data bytes to the requester.
    Reply(Vec<u8>),
    /// Send several replies (ps may need more than one packet).
    Replies(Vec<Vec<u8>>),
    /// Reboot the node (the twin resets it; the host is never touched).
    Reboot,
    /// Set the node's CMP clock to this many UTC seconds and nanoseconds, then reply.
    SetClock { tv_sec: u32, tv_nsec: u32 },
    /// No reply (as libcsp for errors and unknown requests).
    None,
}

/// Answer a request on service port `port` with request data `data`.
///
/// `uptime` is the node's time since boot and `clock` its CMP clock (UTC seconds and
/// nanoseconds).
pub fn handle(
    cfg: &ServiceConfig,
    port: u8,
    data: &[u8],
    uptime: std::time::Duration,
    clock: (u32, u32),
) -> ServiceAction {
    match port {
        PORT_CMP => cmp(cfg, data, clock),
        PORT_PING => ServiceAction::Reply(data.to_vec()),
        PORT_PS => ServiceAction::Replies(
            cfg.ps_text
                .as_bytes()
                .chunks(PS_MTU)
                .map(<[u8]>::to_vec)
                .collect(),
        ),
        PORT_MEMFREE => ServiceAction::Reply(cfg.memfree_bytes.to_be_bytes().to_vec()),
        PORT_REBOOT => match data.get(..4) {
            Some(m) if m == REBOOT_MAGIC.to_be_bytes() => ServiceAction::Reboot,
            _ => ServiceAction::None,
        },
        PORT_BUF_FREE => ServiceAction::Reply(cfg.buffers_free.to_be_bytes().to_vec()),
        PORT_UPTIME => ServiceAction::Reply(match cfg.uptime {
            UptimeFormat::LibcspSecondsBe => u32::try_from(uptime.as_secs())
                .unwrap_or(u32::MAX)
                .to_be_bytes()
                .to_vec(),
            UptimeFormat::IcdMillisLe => {
                // u32 milliseconds wrap after 49.7 days, as a u32 counter on the FC would.
                ((uptime.as_millis() % (1u128 << 32)) as u32)
                    .to_le_bytes()
                    .to_vec()
            }
        }),
        _ => ServiceAction::None,
    }
}

fn cmp(cfg: &ServiceConfig, data: &[u8], clock: (u32, u32)) -> ServiceAction {
    let (Some(&kind), Some(&code)) = (data.first(), data.get(1)) else {
        return ServiceAction::None;
    };
    if kind != CMP_REQUEST {
        return ServiceAction::None;
    }
    match code {
        CMP_IDENT => {
            let mut out = Vec::with_capacity(CMP_IDENT_LEN);
            out.extend_from_slice(&[CMP_REPLY, CMP_IDENT]);
            for (text, len) in [
                (&cfg.hostname, 20),
                (&cfg.model, 30),
                (&cfg.revision, 20),
                (&cfg.date, 12),
                (&cfg.time, 9),
            ] {
                // strncpy then force the last byte to NUL, as csp_cmp_handler does.
                let mut field = vec![0u8; len];
                let n = text.len().min(len - 1);
                field[..n].copy_from_slice(&text.as_bytes()[..n]);
                out.extend_from_slice(&field);
            }
            ServiceAction::Reply(out)
        }
        CMP_CLOCK => {
            // Request and reply: type, code, tv_sec u32 BE, tv_nsec u32 BE. tv_sec 0 reads.
            let Some(body) = data.get(2..10) else {
                return ServiceAction::None;
            };
            let tv_sec = u32::from_be_bytes([body[0], body[1], body[2], body[3]]);
            let tv_nsec = u32::from_be_bytes([body[4], body[5], body[6], body[7]]);
            if tv_sec != 0 {
                return ServiceAction::SetClock { tv_sec, tv_nsec };
            }
            ServiceAction::Reply(clock_reply(clock))
        }
        _ => ServiceAction::None,
    }
}

/// The CMP CLOCK reply for a clock reading.
pub fn clock_reply((tv_sec, tv_nsec): (u32, u32)) -> Vec<u8> {
    let mut out = vec![CMP_REPLY, CMP_CLOCK];
    out.extend_from_slice(&tv_sec.to_be_bytes());
    out.extend_from_slice(&tv_nsec.to_be_bytes());
    out
}

/// Uptime of a node booted at `boot` at time `now`.
pub fn uptime(boot: SimTime, now: SimTime) -> std::time::Duration {
    now.saturating_since(boot)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn cfg() -> ServiceConfig {
        ServiceConfig::named("FC")
    }

    #[test]
    fn uptime_is_big_endian_seconds_by_default() {
        // libcsp-1.4.md section e: reply `00 00 01 7c` = 380 s.
        let a = handle(
            &cfg(),
            PORT_UPTIME,
            &[],
            Duration::from_millis(380_999),
            (0, 0),
        );
        assert_eq!(a, ServiceAction::Reply(vec![0, 0, 0x01, 0x7c]));
    }

    #[test]
    fn uptime_icd_option_is_little_endian_ms() {
        let mut c = cfg();
        c.uptime = UptimeFormat::IcdMillisLe;
        let a = handle(&c, PORT_UPTIME, &[], Duration::from_millis(380_999), (0, 0));
        assert_eq!(a, ServiceAction::Reply(380_999u32.to_le_bytes().to_vec()));
    }

    #[test]
    fn ident_is_93_bytes_nul_terminated() {
        let ServiceAction::Reply(r) = handle(&cfg(), PORT_CMP, &[0, 1], Duration::ZERO, (0, 0))
        else {
            panic!("no reply")
        };
        assert_eq!(r.len(), CMP_IDENT_LEN);
        assert_eq!(&r[..4], &[0xff, 0x01, b'F', b'C']);
        assert_eq!(r[2 + 19], 0);
        assert_eq!(r[2 + 20 + 29], 0);
    }

    #[test]
    fn cmp_errors_get_no_reply() {
        for req in [&[][..], &[0], &[0xff, 1], &[0, 99], &[0, 6, 0]] {
            assert_eq!(
                handle(&cfg(), PORT_CMP, req, Duration::ZERO, (0, 0)),
                ServiceAction::None
            );
        }
    }

    #[test]
    fn reboot_needs_the_magic() {
        let ok = handle(
            &cfg(),
            PORT_REBOOT,
            &[0x80, 0x07, 0x80, 0x07],
            Duration::ZERO,
            (0, 0),
        );
        assert_eq!(ok, ServiceAction::Reboot);
        let bad = handle(
            &cfg(),
            PORT_REBOOT,
            &[0x80, 0x07, 0x80],
            Duration::ZERO,
            (0, 0),
        );
        assert_eq!(bad, ServiceAction::None);
    }

    #[test]
    fn ping_memfree_buffree_ps() {
        let c = cfg();
        assert_eq!(
            handle(&c, PORT_PING, &[1, 2, 3], Duration::ZERO, (0, 0)),
            ServiceAction::Reply(vec![1, 2, 3])
        );
        assert_eq!(
            handle(&c, PORT_MEMFREE, &[], Duration::ZERO, (0, 0)),
            ServiceAction::Reply((128 * 1024u32).to_be_bytes().to_vec())
        );
        assert_eq!(
            handle(&c, PORT_BUF_FREE, &[], Duration::ZERO, (0, 0)),
            ServiceAction::Reply(vec![0, 0, 0, 10])
        );
        let ServiceAction::Replies(ps) = handle(&c, PORT_PS, &[], Duration::ZERO, (0, 0)) else {
            panic!("no ps")
        };
        assert!(ps.iter().all(|p| p.len() <= PS_MTU && !p.contains(&0)));
    }

    #[test]
    fn clock_read_and_set() {
        let read = [0, 6, 0, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            handle(&cfg(), PORT_CMP, &read, Duration::ZERO, (1_577_836_800, 5)),
            ServiceAction::Reply(clock_reply((1_577_836_800, 5)))
        );
        let set = [0, 6, 0x5e, 0x0b, 0xe1, 0x00, 0, 0, 0, 7];
        assert_eq!(
            handle(&cfg(), PORT_CMP, &set, Duration::ZERO, (0, 0)),
            ServiceAction::SetClock {
                tv_sec: 0x5e0b_e100,
                tv_nsec: 7
            }
        );
    }
}
