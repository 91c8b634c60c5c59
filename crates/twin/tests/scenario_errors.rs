//! Bad scenario files get an error naming the file, the line and the field, never a panic.
#![allow(clippy::unwrap_used)]

/// Parse `text` as `bad.toml` and return the first error's (line, field, message).
fn first_error(text: &str) -> (Option<usize>, String, String) {
    let errs =
        m6p_twin::scenario::parse("bad.toml", text).expect_err("the scenario must be rejected");
    let e = errs.0[0].clone();
    let shown = errs.to_string();
    assert!(shown.starts_with("bad.toml:"), "{shown}");
    (e.line, e.field, e.message)
}

fn assert_error(text: &str, line: usize, field: &str, message_part: &str) {
    let (l, f, m) = first_error(text);
    assert_eq!(l, Some(line), "line of `{field}`: {m}");
    assert!(f.contains(field), "field `{f}` should name `{field}` ({m})");
    assert!(
        m.contains(message_part),
        "message `{m}` should contain `{message_part}`"
    );
}

#[test]
fn unknown_top_level_field() {
    assert_error("duration = \"1m\"\ntle2 = 1\n", 2, "tle2", "unknown field");
}

#[test]
fn unknown_field_in_a_table() {
    assert_error(
        "duration = \"1m\"\n[network]\npayloads = [12]\nground = [16]\n",
        4,
        "network.ground",
        "unknown field",
    );
}

#[test]
fn wrong_type() {
    assert_error(
        "duration = \"1m\"\nseed = \"one\"\n",
        2,
        "seed",
        "invalid type",
    );
}

#[test]
fn missing_required_field() {
    let (l, _, m) = first_error("seed = 3\n");
    assert!(m.contains("duration"), "{m}");
    assert!(l.is_some());
}

#[test]
fn bad_duration() {
    assert_error("duration = \"10 parsecs\"\n", 1, "duration", "unknown unit");
}

#[test]
fn payload_address_out_of_range() {
    assert_error(
        "duration = \"1m\"\n[network]\npayloads = [12, 16]\n",
        3,
        "network.payloads[1]",
        "not in 12-15",
    );
}

#[test]
fn unknown_node_name_in_a_command() {
    let text = "duration = \"1m\"\n\n[[commands]]\nat = \"1s\"\nto = \"FCC\"\nrequest = \"ping\"\n";
    assert_error(text, 5, "commands[0].to", "unknown node `FCC`");
}

#[test]
fn unknown_request_kind() {
    let text = "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"pong\"\n";
    assert_error(text, 5, "request", "unknown variant");
}

#[test]
fn raw_request_without_port() {
    let text = "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"raw\"\ndata = \"01\"\n";
    assert_error(text, 5, "commands[0].request", "needs `port`");
}

#[test]
fn bad_hex_data() {
    let text = "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"raw\"\nport = 10\ndata = \"0g\"\n";
    assert_error(text, 7, "commands[0].data", "not hex");
}

#[test]
fn pc_session_for_a_payload_that_does_not_exist() {
    let text =
        "duration = \"1m\"\n[pc]\n[[pc.sessions]]\nid = 1\npayload = 16\nmode = \"polling\"\n";
    assert_error(text, 5, "pc.sessions[0].payload", "not a payload address");
}

#[test]
fn pc_two_sessions_for_one_payload() {
    let text = "duration = \"1m\"\n[[pc.sessions]]\nid = 1\npayload = 12\nmode = \"polling\"\n[[pc.sessions]]\nid = 2\npayload = 12\nmode = \"buffering\"\n";
    assert_error(
        text,
        8,
        "pc.sessions[1].payload",
        "already has pc.sessions[0]",
    );
}

#[test]
fn pc_poll_period_on_a_buffering_session() {
    let text = "duration = \"1m\"\n[[pc.sessions]]\nid = 2\npayload = 13\nmode = \"buffering\"\npoll_period = \"50ms\"\n";
    assert_error(text, 6, "pc.sessions[0].poll_period", "only for polling");
}

#[test]
fn payload_with_an_unknown_behaviour() {
    let text = "duration = \"1m\"\n[[payload]]\naddr = 12\nbehaviour = \"sulky\"\n";
    assert_error(text, 4, "payload[0].behaviour", "unknown behaviour `sulky`");
}

#[test]
fn payload_behaviour_change_needs_its_argument() {
    let text = "duration = \"1m\"\n[[payload]]\naddr = 12\n[[payload.changes]]\nat = \"5s\"\nbehaviour = \"silent-for\"\n";
    assert_error(text, 6, "payload[0].changes[0].behaviour", "needs a count");
}

#[test]
fn payload_that_is_not_simulated() {
    let text = "duration = \"1m\"\n[network]\npayloads = [12]\n[[payload]]\naddr = 14\n";
    assert_error(text, 5, "payload[0].addr", "not a simulated payload");
}

#[test]
fn payload_push_packets_over_256_bytes() {
    let text = "duration = \"1m\"\n[[payload]]\naddr = 13\npush = { rate_bytes_per_s = 100, packet_bytes = 300 }\n";
    assert_error(text, 4, "payload[0].push.packet_bytes", "1-256");
}

#[test]
fn session_expectation_on_an_unknown_session() {
    let text = "duration = \"1m\"\n[[expectations]]\nkind = \"session\"\nsession = 7\nsession_result = \"done\"\n";
    assert_error(text, 4, "expectations[0].session", "no session 7");
}

#[test]
fn downlink_expectation_needs_a_bound() {
    let text = "duration = \"1m\"\n[[expectations]]\nkind = \"downlink\"\nsession = 1\n";
    assert_error(
        text,
        3,
        "expectations[0].kind",
        "needs `min`, `max` or `intact`",
    );
}

#[test]
fn unknown_session_result() {
    let text = "duration = \"1m\"\n[[expectations]]\nkind = \"session\"\nsession = 1\nsession_result = \"fine\"\n";
    assert_error(text, 5, "session_result", "unknown variant");
}

#[test]
fn fault_probability_out_of_range() {
    let text = "duration = \"1m\"\n[[faults]]\nat = \"1s\"\nkind = \"drop\"\ntarget = \"main\"\nprobability = 1.5\n";
    assert_error(text, 6, "faults[0].probability", "not in 0..=1");
}

#[test]
fn fault_on_an_unknown_medium() {
    let text =
        "duration = \"1m\"\n[[faults]]\nat = \"1s\"\nkind = \"link-down\"\ntarget = \"sband\"\n";
    assert_error(text, 5, "faults[0].target", "not a medium");
}

#[test]
fn fault_until_before_at() {
    let text = "duration = \"1m\"\n[[faults]]\nat = \"10s\"\nuntil = \"5s\"\nkind = \"power-off\"\ntarget = \"PC\"\n";
    assert_error(text, 4, "faults[0].until", "after `at`");
}

#[test]
fn expectation_on_an_unknown_command() {
    let text = "duration = \"1m\"\n[[commands]]\nname = \"p\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[expectations]]\nkind = \"reply\"\ncommand = \"q\"\n";
    assert_error(
        text,
        9,
        "expectations[0].command",
        "no command is named `q`",
    );
}

#[test]
fn command_after_an_unknown_command() {
    let text = "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nafter = \"nope\"\nto = \"FC\"\nrequest = \"ping\"\n";
    assert_error(text, 4, "commands[0].after", "no command is named `nope`");
}

#[test]
fn unknown_counter() {
    let text = "duration = \"1m\"\n[[expectations]]\nkind = \"counter\"\ntarget = \"FC\"\ncounter = \"packets_lost\"\nmax = 0\n";
    assert_error(text, 5, "expectations[0].counter", "unknown node counter");
}

#[test]
fn bad_start_time() {
    assert_error(
        "duration = \"1m\"\nstart = \"2026-02-30T00:00:00Z\"\n",
        2,
        "start",
        "not a UTC time",
    );
}

#[test]
fn tle_with_a_bad_checksum() {
    let text = "duration = \"1m\"\n[satellite]\ntle = [\n  \"1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9997\",\n  \"2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009\",\n]\n";
    assert_error(text, 3, "satellite.tle", "the TLE does not parse: line 1");
}

#[test]
fn toml_syntax_error() {
    let (l, _, m) = first_error("duration = \"1m\"\n[network\n");
    assert_eq!(l, Some(2), "{m}");
}

#[test]
fn several_problems_are_all_reported() {
    let text = "duration = \"1m\"\n[network]\npayloads = [11]\nground_stations = [21]\n";
    let errs = m6p_twin::scenario::parse("bad.toml", text).unwrap_err();
    assert_eq!(errs.0.len(), 2, "{errs}");
}

#[test]
fn the_shipped_scenarios_are_valid() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    let mut n = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let text = std::fs::read_to_string(&path).unwrap();
            if let Err(e) = m6p_twin::scenario::parse(&path.display().to_string(), &text) {
                panic!("{e}");
            }
            n += 1;
        }
    }
    assert!(n >= 1);
}

proptest::proptest! {
    #[test]
    fn arbitrary_text_never_panics(text in ".{0,400}") {
        let _ = m6p_twin::scenario::parse("fuzz.toml", &text);
    }
}

#[test]
fn a_field_another_expectation_kind_takes_is_named_with_the_accepted_ones() {
    let (l, f, m) = first_error(
        "duration = \"1m\"\n[[expectations]]\nkind = \"beacon\"\nmin = 1\nquantity = \"soc\"\n",
    );
    assert_eq!(l, Some(5));
    assert!(f.contains("expectations[0].quantity"), "{f}");
    assert!(
        m.contains("a `beacon` expectation takes no `quantity`")
            && m.contains("within, min, max, target, from, to"),
        "{m}"
    );
    assert_error(
        "duration = \"1m\"\n[[commands]]\nname = \"p\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[expectations]]\nkind = \"no-reply\"\ncommand = \"p\"\nwithin = \"1s\"\n",
        10,
        "expectations[0].within",
        "a `no-reply` expectation takes no `within`",
    );
}

#[test]
fn a_beacon_expectation_names_a_comm_as_its_sender() {
    assert_error(
        "duration = \"1m\"\n[[expectations]]\nkind = \"beacon\"\nmin = 1\ntarget = \"FC\"\n",
        5,
        "expectations[0].target",
        "the sending COMM: COMM1 or COMM2",
    );
    assert_error(
        "duration = \"2m\"\n[[expectations]]\nkind = \"beacon\"\nmin = 1\nfrom = \"60s\"\nto = \"30s\"\n",
        6,
        "expectations[0].to",
        "must be after `from`",
    );
}

#[test]
fn a_type_error_in_an_array_of_tables_names_the_entry() {
    assert_error(
        "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[commands]]\nat = \"6 hours\"\nto = \"FC\"\nrequest = \"ping\"\n",
        7,
        "commands[1].at",
        "unknown unit",
    );
    assert_error(
        "duration = \"1m\"\n[[eps.events]]\nat = \"1s\"\nsoc = 0.5\n[[eps.events]]\nat = \"2s\"\nsoc = \"half\"\n",
        7,
        "eps.events[1].soc",
        "invalid type",
    );
}

/// `after` needs both commands sent from one station; GS16 named or left to the default is
/// the same station (it was taken for another one).
#[test]
fn after_across_gs16_named_and_gs16_by_default_is_accepted() {
    let text = "duration = \"1m\"\n[[commands]]\nname = \"a\"\nfrom = \"GS16\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[commands]]\nafter = \"a\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n";
    m6p_twin::scenario::parse("ok.toml", text).unwrap();
    let other = "duration = \"1m\"\n[network]\nground_stations = [16, 17]\n[[commands]]\nname = \"a\"\nfrom = \"GS17\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[commands]]\nafter = \"a\"\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n";
    assert_error(
        other,
        11,
        "commands[1].after",
        "sent from another ground station",
    );
}

#[test]
fn an_expectation_window_after_the_end_of_the_run() {
    assert_error(
        "duration = \"1m\"\n[[expectations]]\nkind = \"beacon\"\nmin = 1\nfrom = \"300s\"\n",
        5,
        "expectations[0].from",
        "after the end of the run (1m)",
    );
}

#[test]
fn array_entries_are_named_whatever_the_header_spacing_and_comments() {
    // A comment after the header, spaces inside the brackets.
    assert_error(
        "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[ commands ]]   # second\nat = \"6 hours\"\nto = \"FC\"\nrequest = \"ping\"\n",
        7,
        "commands[1].at",
        "unknown unit",
    );
    // A missing field: the error points at the entry's header.
    let (_, f, m) = first_error(
        "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FC\"\nrequest = \"ping\"\n[[commands]]\nat = \"2s\"\nrequest = \"ping\"\n",
    );
    assert!(m.contains("missing field `to`"), "{m}");
    assert_eq!(f, "commands[1]");
}

#[test]
fn fc_periodic_telemetry_and_safe_settings_are_checked_where_they_are_written() {
    let periodic = |body: &str| format!("duration = \"1m\"\n[fc.periodic]\n{body}");
    assert_error(
        &periodic("to = \"GS16\"\nport = 3\nevery = \"1s\"\ntelemetry = [\"TMGEN\"]\n"),
        4,
        "fc.periodic.port",
        "7-63",
    );
    assert_error(
        &periodic("to = \"GS16\"\nport = 20\nevery = \"50ms\"\ntelemetry = [\"TMGEN\"]\n"),
        5,
        "fc.periodic.every",
        "100 ms to 1 h",
    );
    assert_error(
        &periodic("to = \"FC\"\nport = 20\nevery = \"1s\"\ntelemetry = [\"TMGEN\"]\n"),
        3,
        "fc.periodic.to",
        "other than the FC",
    );
    assert_error(
        &periodic("to = \"GS16\"\nport = 20\nevery = \"1s\"\ntelemetry = [\"TMPC\"]\n"),
        6,
        "fc.periodic.telemetry",
        "`TMPC` is not one of TMGEN",
    );
    assert_error(
        "duration = \"1m\"\n[fc.safe]\nenter_soc = 0.4\nexit_soc = 0.2\n",
        2,
        "fc.safe",
        "below the entry's",
    );
    // A good one parses.
    m6p_twin::scenario::parse(
        "ok.toml",
        &periodic("to = \"GS16\"\nport = 20\nevery = \"1s\"\ntelemetry = [\"tmgen\", \"TMATP\"]\n"),
    )
    .unwrap();
}

/// Issue 19: a typed ICD command is checked against the ICD's ranges before the run, and
/// the error names the file, the line, the field and the range.
#[test]
fn a_typed_setup_of_1000_s_is_refused_with_the_icd_range() {
    let text = "duration = \"1m\"\n\
                [network]\npayloads = [12]\n\
                [[commands]]\nfrom = \"GS16\"\nat = \"1s\"\ncommand = \"PC.SETUP\"\n\
                args = { session_id = 1, timestamp = \"now\", max_packets = 0, poll_frame_size = 200,\n\
                \x20 duration_s = 1000 }\n";
    assert_error(
        text,
        9,
        "commands[0].args.duration_s",
        "1000 is outside the ICD's range 5..=900",
    );
    // The same with the good duration passes; a wrong node, a missing field and an unknown
    // command are named.
    m6p_twin::scenario::parse("ok.toml", &text.replace("1000", "\"10m\"")).unwrap();
    assert_error(
        &text.replace(
            "command = \"PC.SETUP\"",
            "to = \"FC\"\ncommand = \"PC.SETUP\"",
        ),
        7,
        "commands[0].to",
        "goes to the PC (6), not to 3",
    );
    assert_error(
        &text.replace("timestamp = \"now\", ", ""),
        8,
        "commands[0].args",
        "missing: SETUP needs timestamp",
    );
    assert_error(
        &text.replace("PC.SETUP", "PC.SETPU"),
        7,
        "commands[0].command",
        "the PC has no command `SETPU`: SETUP, STATUS, ABORT",
    );
}

/// Issue 19: a `field` expectation names an ICD reply's field; a wrong node, command, field
/// or value name, or `when = "at"` without `at`, is refused naming the line and the key.
#[test]
fn a_field_expectation_is_checked_against_the_icd() {
    let text = "duration = \"1m\"\n\
                [[expectations]]\nkind = \"field\"\nfield = \"FC.TMGEN.current_mode\"\n\
                equals = \"nadir\"\n";
    m6p_twin::scenario::parse("ok.toml", text).unwrap();
    assert_error(
        &text.replace("current_mode", "mode"),
        4,
        "expectations[0].field",
        "FC.TMGEN's reply has no field `mode`: rtc_timestamp, uptime_s",
    );
    assert_error(
        &text.replace("TMGEN", "TMGNE"),
        4,
        "expectations[0].field",
        "the FC has no command `TMGNE`",
    );
    assert_error(
        &text.replace("\"nadir\"", "\"sideways\""),
        5,
        "expectations[0].equals",
        "`sideways` is not a value of `current_mode`: idle, detumble",
    );
    assert_error(
        &format!("{text}when = \"at\"\n"),
        2,
        "expectations[0].at",
        "`when = \"at\"` needs `at`",
    );
    assert_error(
        &text.replace("equals = \"nadir\"\n", ""),
        3,
        "expectations[0].kind",
        "needs `equals`, `above` or `below`",
    );
}

/// A `drops.<reason>` counter names one of the node's drop reasons (`csp::drop::DropReason`):
/// a misspelt reason is an error listing them, not a counter that always reads 0.
#[test]
fn a_drop_counter_names_a_known_reason() {
    let text = "duration = \"1m\"\n[[expectations]]\nkind = \"counter\"\ntarget = \"PC\"\ncounter = \"drops.unbound-port\"\nmax = 0\n";
    assert_error(
        text,
        5,
        "expectations[0].counter",
        "unknown drop reason `unbound-port` (reasons: frame on non-CAN iface, cfp, no route",
    );
    m6p_twin::scenario::parse("ok.toml", &text.replace("unbound-port", "unbound port")).unwrap();
}
