//! WHY (control port, command 4: the twin's own): the PC tells an address why it refused
//! that address's last refused request, and tells every other address that it refused
//! none of theirs.
#![allow(clippy::unwrap_used)]

mod util;

use m6p_nodes_pc::wire::{self, RefusalCode, Why};
use util::*;

/// WHY asked from `src` (the reply, parsed): from the ground station's address through
/// [`Sim::request`], from any other as a stray packet.
fn why(s: &mut Sim, src: u8) -> Why {
    let r = if src == GS {
        s.request(wire::PORT_CONTROL, &[wire::cmd::WHY])
    } else {
        s.send_from(src, 40, wire::PORT_CONTROL, &[wire::cmd::WHY]);
        let p = s.stray.pop().unwrap();
        assert_eq!((p.header.dst, p.header.dport), (src, 40));
        p.data
    };
    assert_eq!(r[..2], [wire::cmd::WHY, 1], "WHY is always answered");
    Why::parse(&r[2..]).unwrap()
}

#[test]
fn why_tells_the_refused_address_its_reason_and_others_none() {
    let mut s = Sim::new(
        cfg(),
        vec![FakePayload::normal(12), FakePayload::normal(14)],
    );
    // Nothing refused yet.
    assert_eq!(why(&mut s, GS).code, RefusalCode::None);
    // SETUP of a session that is not configured: the ICD's failure reply, a result only.
    assert_eq!(s.setup(&session(9, ts(100), 60, 0, 64, b"")), 0);
    let w = why(&mut s, GS);
    assert_eq!(
        w,
        Why {
            code: RefusalCode::UnknownSession,
            port: wire::PORT_CONTROL,
            command: wire::cmd::SETUP,
            session_id: 9,
            other_session_id: 0,
            reason: "no session 9 is configured".to_owned(),
        }
    );
    // Another address was refused nothing.
    let other = why(&mut s, 20);
    assert_eq!(
        (other.code, other.port, other.command),
        (RefusalCode::None, 0, 0)
    );
    // Asking again does not clear it; an accepted request leaves it.
    assert_eq!(s.setup(&session(1, ts(100), 60, 0, 64, b"")), 1);
    assert_eq!(why(&mut s, GS), w);
    // The next refusal takes its place: an overlap names both sessions.
    assert_eq!(s.setup(&session(3, ts(110), 60, 0, 64, b"")), 0);
    let w = why(&mut s, GS);
    assert_eq!(
        (w.code, w.session_id, w.other_session_id, w.reason.as_str()),
        (RefusalCode::Overlap, 3, 1, "window overlaps session 1")
    );
    // A request that does not parse is a refusal too.
    assert_eq!(s.request(wire::PORT_CONTROL, &[wire::cmd::STATUS]), [2, 0]);
    let w = why(&mut s, GS);
    assert_eq!(
        (w.code, w.command),
        (RefusalCode::Malformed, wire::cmd::STATUS)
    );
    // A payload refused SETUP (ICD 3.1.1) may ask why, as it may ask STATUS.
    let setup = session(3, ts(500), 60, 0, 64, b"").to_request();
    s.send_from(15, 41, wire::PORT_CONTROL, &setup);
    assert_eq!(s.stray.pop().unwrap().data, [wire::cmd::SETUP, 0]);
    let w = why(&mut s, 15);
    assert_eq!(
        (w.code, w.reason.as_str()),
        (
            RefusalCode::PayloadDenied,
            "payloads may not SETUP (ICD 3.1.1)"
        )
    );
    // A reboot forgets.
    let now = s.now;
    s.host.reboot(now);
    assert_eq!(why(&mut s, GS).code, RefusalCode::None);
}
