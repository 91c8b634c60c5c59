//! The PC's buffer files (port 13; ICD 3.1.5 "a regular file system interface") on a
//! running twin, used by an independent Python client written from docs/protocol.md
//! (`tests/pc_files_decode.py`) over a real KISS/TCP socket as ground node 17, while payload
//! 13 pushes 200-byte packets of its stream at 2000 B/s: FLIST, FSTAT, FREAD at stream
//! offsets, FDELETE, the failure replies, and a payload refused. Every byte read must be the
//! bytes payload 13 pushed at that stream offset (its packets on the payload bus, from the
//! run's trace), and what FDELETE removed is accounted as `deleted`. Real time, about 8 s.
#![allow(clippy::unwrap_used)]

#[path = "common/decoder.rs"]
mod decoder;

#[test]
fn python_client_lists_reads_and_deletes_the_buffer_file_at_stream_offsets() {
    let mut opts = decoder::default_scenario_options(8);
    opts.trace = true;
    opts.payloads.insert(
        13,
        nodes_payload::PayloadConfig {
            push: Some(nodes_payload::PushConfig {
                packet_bytes: 200,
                rate_bytes_per_s: 2000,
                ..nodes_payload::PushConfig::default()
            }),
            ..nodes_payload::PayloadConfig::default()
        },
    );
    let (text, report) = decoder::run_decoder(opts, "pc_files_decode.py", &[], 18);

    // The stream payload 13 pushed into the PC's ingest port, in order.
    let stream: Vec<u8> = decoder::packets_on(&report, "payload", "PL13")
        .into_iter()
        .filter(|(_, p)| p.header.dst == 6 && p.header.dport == 11)
        .flat_map(|(_, p)| p.data)
        .collect();
    assert!(stream.len() >= 2000, "{} bytes pushed", stream.len());
    let mut reads = 0;
    for line in text.lines().filter_map(|l| l.strip_prefix("READ ")) {
        let (offset, hex_bytes) = line.split_once(' ').unwrap();
        let offset: usize = offset.parse().unwrap();
        let bytes = hex::decode(hex_bytes).unwrap();
        assert_eq!(
            stream.get(offset..offset + bytes.len()),
            Some(bytes.as_slice()),
            "FREAD at {offset}"
        );
        reads += 1;
    }
    assert!(reads >= 3, "{text}");
    let deleted = report
        .sessions
        .dropped
        .get(&(13, "deleted".to_owned()))
        .copied()
        .unwrap_or(0);
    assert!(deleted > 0, "{:?}", report.sessions.dropped);
}
