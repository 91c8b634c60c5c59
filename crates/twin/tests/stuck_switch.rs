//! The `stuck-switch` fault on a real run: while PL12's switch is stuck, a CHSET to switch
//! it off is answered with success and channel states that show it still on, the EPS
//! reports no switch and payload 12 still answers a ping; freed, the same CHSET switches
//! it off and the payload goes silent.
#![allow(clippy::unwrap_used)]

use csp::SimTime;
use m6p_twin::events::RunEvent;
use m6p_twin::exec::execute;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;

const SCENARIO: &str = r#"
name = "stuck-switch"
duration = "60s"

[fc]
publish_hz = 0

[[faults]]
kind = "stuck-switch"
target = "EPS"
channel = "PL12"
at = "5s"
until = "30s"

[[commands]]
name = "pl12-off-while-stuck"
at = "10s"
command = "EPS.CHSET"
args = { channel = "PL12", on = "off" }

[[commands]]
name = "ping-pl12-while-stuck"
at = "20s"
to = 12
request = "ping"

[[commands]]
name = "pl12-off-when-freed"
at = "40s"
command = "EPS.CHSET"
args = { channel = "PL12", on = "off" }

[[commands]]
name = "ping-pl12-when-off"
at = "50s"
to = 12
request = "ping"

# The channel states after each CHSET: every channel on but PL14 and PL15 (0x013f, the
# default network's), then PL12 (bit 4) off too (0x012f); none shed.
[[expectations]]
name = "CHSET succeeds and PL12 stays on"
kind = "reply"
command = "pl12-off-while-stuck"
data = "03 01 3f 01 00 00"

[[expectations]]
name = "payload 12 still powered"
kind = "reply"
command = "ping-pl12-while-stuck"

[[expectations]]
name = "freed, CHSET switches PL12 off"
kind = "reply"
command = "pl12-off-when-freed"
data = "03 01 2f 01 00 00"

[[expectations]]
name = "payload 12 unpowered"
kind = "no-reply"
command = "ping-pl12-when-off"
"#;

#[test]
fn a_stuck_switch_ignores_chset_until_it_is_freed() {
    let s = m6p_twin::scenario::parse("stuck-switch.toml", SCENARIO).unwrap();
    let compiled = compile(&s);
    let rt = build_runtime().unwrap();
    let mut pl12 = Vec::new();
    let mut faults = Vec::new();
    let out = rt
        .block_on(execute(compiled, &mut |ev| match ev {
            RunEvent::Eps(o) => {
                if let nodes_eps::EpsOutput::Channel { t, channel, on, .. } = **o
                    && channel == nodes_eps::Channel::Payload12
                {
                    pl12.push((t, on));
                }
            }
            RunEvent::Fault { t, what, .. } => faults.push((*t, what.clone())),
            _ => {}
        }))
        .unwrap();
    print!("{}", out.verdict_table());
    assert!(out.passed(), "{}", out.verdict_table());
    // PL12 switched once: off, by the CHSET sent at 40 s as it arrives; none at 10 s.
    assert_eq!(pl12.len(), 1, "{pl12:?}");
    assert!(!pl12[0].1);
    assert!(
        pl12[0].0 > SimTime::from_secs(40) && pl12[0].0 < SimTime::from_secs(41),
        "{pl12:?}"
    );
    assert_eq!(
        faults,
        vec![
            (
                SimTime::from_secs(5),
                "faults[0]: StuckSwitch on EPS".to_owned()
            ),
            (
                SimTime::from_secs(30),
                "faults[0]: StuckSwitch on EPS (freed)".to_owned()
            ),
        ]
    );
}
