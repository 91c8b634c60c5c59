//! The FC's state (TMGEN `current_state`): NOMINAL, or SAFE while the battery is low or
//! the ADCS has fallen back from its estimator.
//!
//! - **Low battery.** The FC reads the EPS's TMEPS (EPS port 10, command 1) every
//!   [`SafeConfig::eps_poll`] from an ephemeral port of its own, as a flight computer's
//!   housekeeping loop does, and takes the state of charge from it. Below
//!   [`SafeConfig::enter_soc`] the battery is low; it is low again only once it has come back
//!   to [`SafeConfig::exit_soc`] (hysteresis). While it is low the FC asks the ADCS for sun
//!   max power whatever was commanded (scripts wait); ATCMDSET still sets the commanded mode,
//!   which comes back when the battery does. A TMEPS that does not come, or does not parse,
//!   changes nothing (counted).
//! - **Estimator failure.** While the ADCS's own health monitor holds it in its safe
//!   fallback (detumble, `Adcs::fallback_reason`), the FC is SAFE too; nothing more is
//!   needed, the ADCS already does without its estimate.
//!
//! Every change of state is a log line (a warning into SAFE with its cause, info back to
//! NOMINAL), recorded with the run. The state is volatile: a reboot starts NOMINAL and polls
//! at once.

use std::time::Duration;

use csp::node::Node;
use csp::reqrep::le::Repr;
use csp::{Header, Packet, SimTime};

/// TMGEN `current_state`: nominal.
pub const STATE_NOMINAL: u8 = 0;
/// TMGEN `current_state`: safe.
pub const STATE_SAFE: u8 = 1;

/// When the FC goes SAFE.
#[derive(Debug, Clone, PartialEq)]
pub struct SafeConfig {
    /// How often the FC reads the EPS (`None`: never; the battery then never makes it SAFE).
    pub eps_poll: Option<Duration>,
    /// The EPS's address and port.
    pub eps: (u8, u8),
    /// State of charge below which the battery is low, 0..=1.
    pub enter_soc: f64,
    /// State of charge at which a low battery is no longer low, 0..=1, not below
    /// `enter_soc`.
    pub exit_soc: f64,
}

impl Default for SafeConfig {
    /// TMEPS every 30 s; low below 15 %, until back at 30 %.
    fn default() -> Self {
        SafeConfig {
            eps_poll: Some(Duration::from_secs(30)),
            eps: (platform::addr::EPS, icd::eps::PORT_EPS),
            enter_soc: 0.15,
            exit_soc: 0.30,
        }
    }
}

/// What is wrong with a safe-mode configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SafeConfigError {
    /// A threshold outside 0..=1.
    #[error("safe-mode state of charge thresholds must be within 0-1")]
    ThresholdRange,
    /// Safe mode would be left below the charge it is entered at.
    #[error("safe-mode exit state of charge {exit_soc} is below the entry's {enter_soc}")]
    ExitBelowEnter {
        /// The exit threshold, fraction of full.
        exit_soc: f64,
        /// The entry threshold, fraction of full.
        enter_soc: f64,
    },
    /// A zero poll period.
    #[error("the EPS poll period must be above zero (or none)")]
    ZeroPoll,
}

impl SafeConfig {
    /// Thresholds within 0..=1, exit not below enter, a poll period above zero.
    pub fn validate(&self) -> Result<(), SafeConfigError> {
        let unit = 0.0..=1.0;
        if !unit.contains(&self.enter_soc) || !unit.contains(&self.exit_soc) {
            return Err(SafeConfigError::ThresholdRange);
        }
        if self.exit_soc < self.enter_soc {
            return Err(SafeConfigError::ExitBelowEnter {
                exit_soc: self.exit_soc,
                enter_soc: self.enter_soc,
            });
        }
        if self.eps_poll == Some(Duration::ZERO) {
            return Err(SafeConfigError::ZeroPoll);
        }
        Ok(())
    }
}

/// Why the FC is SAFE.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafeCause {
    /// The battery is low.
    LowBattery,
    /// The ADCS fell back from its estimator (the reason it gives).
    Estimator(adcs::adcs::FallbackReason),
}

/// The FC's state machine and its EPS housekeeping (volatile).
#[derive(Debug, Clone)]
pub struct SafeMonitor {
    cfg: SafeConfig,
    port: Option<u8>,
    next_poll: Option<SimTime>,
    /// The last state of charge read, 0..=1.
    pub soc: Option<f64>,
    low_battery: bool,
    cause: Option<SafeCause>,
    /// TMEPS requests sent.
    pub polls: u64,
    /// TMEPS replies taken.
    pub replies: u64,
    /// Replies that were not a TMEPS of the right size (ignored).
    pub bad_replies: u64,
}

impl SafeMonitor {
    /// The running configuration (platform parameters change it).
    pub fn config_mut(&mut self) -> &mut SafeConfig {
        &mut self.cfg
    }
    /// A monitor by `cfg`, NOMINAL, not polling yet.
    pub fn new(cfg: SafeConfig) -> Self {
        SafeMonitor {
            cfg,
            port: None,
            next_poll: None,
            soc: None,
            low_battery: false,
            cause: None,
            polls: 0,
            replies: 0,
            bad_replies: 0,
        }
    }

    /// At boot: NOMINAL, a port for the EPS's replies, the first poll at once.
    pub fn start(&mut self, node: &mut Node, now: SimTime) {
        *self = SafeMonitor::new(self.cfg.clone());
        if self.cfg.eps_poll.is_some() {
            self.port = node.alloc_port();
            self.next_poll = Some(now);
        }
    }

    /// TMGEN's `current_state`.
    pub fn state(&self) -> u8 {
        if self.cause.is_some() {
            STATE_SAFE
        } else {
            STATE_NOMINAL
        }
    }

    /// Why the FC is SAFE, if it is.
    pub fn cause(&self) -> Option<SafeCause> {
        self.cause
    }

    /// Whether the battery is low (the FC then asks for sun max power).
    pub fn low_battery(&self) -> bool {
        self.low_battery
    }

    /// When the next poll is due.
    pub fn due(&self) -> Option<SimTime> {
        self.next_poll
    }

    /// Poll the EPS if due.
    pub fn run(&mut self, node: &mut Node, now: SimTime) {
        let (Some(port), Some(t), Some(period)) = (self.port, self.next_poll, self.cfg.eps_poll)
        else {
            return;
        };
        if t > now {
            return;
        }
        self.next_poll = Some(now + period);
        let (eps, eps_port) = self.cfg.eps;
        let header = Header::new(node.addr(), eps, eps_port, port);
        // A send failure is counted by the node.
        if node
            .send(Packet::new(header, vec![icd::eps::cmd::TMEPS]), now)
            .is_ok()
        {
            self.polls += 1;
        }
    }

    /// The thresholds changed (a platform parameter): judge the last state of charge read
    /// against them at once, not at the next poll.
    pub fn rejudge(&mut self) {
        if let Some(soc) = self.soc {
            self.judge(soc);
        }
    }

    fn judge(&mut self, soc: f64) {
        if soc < self.cfg.enter_soc {
            self.low_battery = true;
        } else if soc >= self.cfg.exit_soc {
            self.low_battery = false;
        }
    }

    /// Take `packet` if it is the EPS's answer to a poll; `false` if it is not for us.
    pub fn handle_reply(&mut self, packet: &Packet) -> bool {
        let (eps, eps_port) = self.cfg.eps;
        if self.port.is_none()
            || Some(packet.header.dport) != self.port
            || packet.header.src != eps
            || packet.header.sport != eps_port
        {
            return false;
        }
        let d = &packet.data;
        let tm = (d.get(..2) == Some(&[icd::eps::cmd::TMEPS, 1][..]))
            .then(|| icd::eps::TmEps::parse(&d[2..]).ok())
            .flatten()
            .filter(|t| t.soc.is_finite());
        match tm {
            Some(t) => {
                self.replies += 1;
                let soc = f64::from(t.soc);
                self.soc = Some(soc);
                self.judge(soc);
            }
            None => self.bad_replies += 1,
        }
        true
    }

    /// The state after the ADCS's tick (`fallback`: its fallback reason, if any). A change
    /// of state comes back as its log line and whether it is a warning.
    pub fn update(
        &mut self,
        fallback: Option<adcs::adcs::FallbackReason>,
    ) -> Option<(bool, String)> {
        let cause = if self.low_battery {
            Some(SafeCause::LowBattery)
        } else {
            fallback.map(SafeCause::Estimator)
        };
        if cause == self.cause {
            return None;
        }
        let soc = self.soc.map_or(String::new(), |s| {
            format!(", state of charge {:.1} %", s * 100.0)
        });
        let line = match cause {
            Some(SafeCause::LowBattery) => (
                true,
                format!(
                    "fc: SAFE: battery low (below {:.0} %{soc}): sun max power until {:.0} %",
                    self.cfg.enter_soc * 100.0,
                    self.cfg.exit_soc * 100.0
                ),
            ),
            Some(SafeCause::Estimator(why)) => (
                true,
                format!("fc: SAFE: the ADCS fell back from its estimator ({why})"),
            ),
            None => (false, format!("fc: NOMINAL{soc}")),
        };
        self.cause = cause;
        Some(line)
    }
}

// The FC's SAFE monitor: its configuration (parameters 11 and 12 change it), the EPS
// poll's schedule, the last state of charge, the cause it is SAFE for, counts.
snap::fields!(SafeConfig {
    eps_poll,
    eps,
    enter_soc,
    exit_soc
});
snap::fields!(SafeMonitor {
    cfg,
    port,
    next_poll,
    soc,
    low_battery,
    cause,
    polls,
    replies,
    bad_replies
});

snap::tagged_enum!(SafeCause {
    LowBattery,
    Estimator(why)
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn thresholds_are_checked() {
        assert!(SafeConfig::default().validate().is_ok());
        let bad = |enter_soc, exit_soc| SafeConfig {
            enter_soc,
            exit_soc,
            ..SafeConfig::default()
        };
        assert!(bad(0.3, 0.2).validate().is_err());
        assert!(bad(-0.1, 0.2).validate().is_err());
        assert!(bad(0.1, 1.5).validate().is_err());
        let c = SafeConfig {
            eps_poll: Some(Duration::ZERO),
            ..SafeConfig::default()
        };
        assert!(c.validate().is_err());
    }

    #[test]
    fn the_cause_follows_the_battery_with_hysteresis_then_the_estimator() {
        let mut m = SafeMonitor::new(SafeConfig::default());
        m.port = Some(40);
        let tm = |soc: f32| {
            let t = icd::eps::TmEps {
                soc,
                ..icd::eps::TmEps::default()
            };
            let mut d = vec![1, 1];
            t.emit(&mut d);
            Packet::new(Header::new(4, 3, 40, 10), d)
        };
        assert_eq!(m.update(None), None);
        assert!(m.handle_reply(&tm(0.10)));
        let (warn, line) = m.update(None).unwrap();
        assert!(
            warn && line.contains("battery low") && line.contains("10.0 %"),
            "{line}"
        );
        assert_eq!(m.state(), STATE_SAFE);
        // 20 % is not yet back: still low; an estimator fallback does not hide the battery.
        m.handle_reply(&tm(0.20));
        let gated = Some(adcs::adcs::FallbackReason::Gated);
        assert_eq!(m.update(gated), None);
        m.handle_reply(&tm(0.30));
        let (_, line) = m.update(gated).unwrap();
        assert!(
            line.contains("estimator (estimator unhealthy: updates gated out)"),
            "{line}"
        );
        let (warn, line) = m.update(None).unwrap();
        assert!(!warn && line.starts_with("fc: NOMINAL"), "{line}");
        assert_eq!(m.state(), STATE_NOMINAL);
        // Not ours: another port, another node; ours but not a TMEPS: counted, ignored.
        assert!(!m.handle_reply(&Packet::new(Header::new(4, 3, 41, 10), vec![1, 1])));
        assert!(!m.handle_reply(&Packet::new(Header::new(5, 3, 40, 10), vec![1, 1])));
        assert!(m.handle_reply(&Packet::new(Header::new(4, 3, 40, 10), vec![1, 0])));
        assert!(m.handle_reply(&tm(f32::NAN)));
        assert_eq!((m.replies, m.bad_replies), (3, 2));
        assert_eq!(m.soc, Some(f64::from(0.30f32)));
    }
}
