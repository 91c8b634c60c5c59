//! libcsp 1.4 against the project's CSP stack, side by side in one process (issue 17):
//! KISS encode (64 and 200 bytes), CFP fragmentation (64, 200), CRC-32C (64, 256) and a
//! loopback ping (64). What one iteration is on each side is in the `m6p-libcsp-compare`
//! crate documentation (`src/lib.rs`); in short:
//!
//! - KISS: libcsp = `csp_buffer_get` + copy + its KISS transmit (`csp_kiss_tx`, CRC32C,
//!   putc per byte into memory, buffer freed); ours = `kiss::encode` into a reused `Vec`.
//! - CFP: libcsp = `csp_buffer_get` + copy + `csp_can_tx` into a dummy driver that copies
//!   frames, every next frame sent from the driver's "transmit complete" callback; ours =
//!   `Fragmenter::fragment` into a reused `Vec`.
//! - CRC: `csp_crc32_memory` against `crc32::crc32c`.
//! - ping: libcsp = `csp_ping` to its own address (timeout 1000 ms) through the loopback
//!   interface, its router task and a server thread running `csp_service_handler`, so
//!   thread wake-ups are most of it; ours = a `Node` pinging its own address with
//!   `client::Client` through its loopback queue and service handler, in one thread.
//!
//! Method: a calibration run per side and case (also the warm-up) picks the iteration count
//! so that one measurement takes about 30 ms, and checks that both sides produced the same
//! bytes (KISS frame, CAN frames but the CFP ident, CRC value; the ping was answered). Then
//! 5 rounds; each round measures every case on both sides one after the other, libcsp first
//! in even rounds and ours first in odd ones. Per case and side: the median of the 5
//! per-iteration times, their spread (min-max), and the ratio libcsp / ours of the medians.
//! For reference, libcsp's buffer handling alone (`csp_buffer_get` + copy +
//! `csp_buffer_free`, part of its KISS and CFP rows) is measured in the same rounds.
//!
//! Acceptance (issue 17): CRC-32C at least 10x libcsp, KISS encode at least 3x at 64 and
//! 200 bytes. The verdicts are printed; the exit status does not depend on them.
//!
//! Run (libcsp is built by the crate's build script; needs a C compiler):
//!
//! ```sh
//! cargo bench -p m6p-libcsp-compare --bench vs_libcsp            # table on stdout
//! cargo bench -p m6p-libcsp-compare --bench vs_libcsp -- --json  # one JSON object on stdout, table on stderr
//! M6P_BENCH_JSON=1 cargo bench -p m6p-libcsp-compare --bench vs_libcsp   # the same
//! ```

use std::fmt::Write as _;
use std::time::Duration;

use m6p_libcsp_compare::{CASES, Case, Op, Sample, Side};
use serde_json::{Value, json};

/// Rounds (the figures are medians of this many).
const ROUNDS: usize = 5;
/// Aim for one measurement.
const TARGET: Duration = Duration::from_millis(30);
/// A calibration run at least this long sets the iteration count.
const CALIBRATE_MIN: Duration = Duration::from_millis(5);
/// The issue's acceptance: (op, bytes, least ratio libcsp / ours).
const ACCEPTANCE: [(Op, usize, f64); 4] = [
    (Op::Crc32c, 64, 10.0),
    (Op::Crc32c, 256, 10.0),
    (Op::KissEncode, 64, 3.0),
    (Op::KissEncode, 200, 3.0),
];
/// Data lengths of the libcsp buffer-handling reference rows.
const BUFFER_LENS: [usize; 2] = [64, 200];

/// The 5 per-iteration times of one case on one side.
#[derive(Debug, Default, Clone)]
struct Series {
    iters: u64,
    ns: Vec<f64>,
}

impl Series {
    fn sorted(&self) -> Vec<f64> {
        let mut v = self.ns.clone();
        v.sort_by(f64::total_cmp);
        v
    }
    fn median(&self) -> f64 {
        let v = self.sorted();
        match v.len() {
            0 => f64::NAN,
            n if n % 2 == 1 => v[n / 2],
            n => (v[n / 2 - 1] + v[n / 2]) / 2.0,
        }
    }
    fn min(&self) -> f64 {
        self.sorted().first().copied().unwrap_or(f64::NAN)
    }
    fn max(&self) -> f64 {
        self.sorted().last().copied().unwrap_or(f64::NAN)
    }
    fn json(&self) -> Value {
        json!({
            "median_ns": self.median(),
            "min_ns": self.min(),
            "max_ns": self.max(),
            "iters": self.iters,
            "rounds_ns": self.ns,
        })
    }
}

fn measure(side: Side, case: Case, iters: u64) -> Sample {
    m6p_libcsp_compare::measure(side, case, iters)
        .unwrap_or_else(|e| panic!("{} {} {} B: {e}", side.name(), case.op.name(), case.len))
}

/// Iterations for about [`TARGET`]; the last calibration sample (its output).
fn calibrate(side: Side, case: Case) -> (u64, Sample) {
    let mut n = 1u64;
    loop {
        let s = measure(side, case, n);
        if s.ns >= CALIBRATE_MIN.as_nanos() as u64 {
            let iters = (n as f64 * TARGET.as_nanos() as f64 / s.ns as f64).round() as u64;
            return (iters.max(1), s);
        }
        n = n.saturating_mul(4);
    }
}

/// Iterations of libcsp's buffer cycle for about [`TARGET`].
fn calibrate_buffer(len: usize) -> u64 {
    let mut n = 1u64;
    loop {
        let ns = m6p_libcsp_compare::libcsp_buffer_cycle(len, n).expect("buffer cycle");
        if ns >= CALIBRATE_MIN.as_nanos() as u64 {
            return ((n as f64 * TARGET.as_nanos() as f64 / ns as f64).round() as u64).max(1);
        }
        n = n.saturating_mul(4);
    }
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_owned))
        .unwrap_or_else(|| "?".to_owned())
}

fn main() {
    let json_out = std::env::args().any(|a| a == "--json")
        || std::env::var("M6P_BENCH_JSON").is_ok_and(|v| !v.is_empty() && v != "0");
    if !m6p_libcsp_compare::libcsp_available() {
        eprintln!(
            "vs_libcsp: libcsp 1.4 was not built (no C compiler `cc`, or M6P_LIBCSP_PROBE=off): nothing to compare"
        );
        std::process::exit(1);
    }
    m6p_libcsp_compare::libcsp_init().expect("libcsp setup");
    let load_before = load_average();

    // Calibration: iteration counts, warm-up, and the same-output check.
    let mut series: Vec<[Series; 2]> = Vec::new();
    for case in CASES {
        let (li, ls) = calibrate(Side::Libcsp, case);
        let (oi, os) = calibrate(Side::Ours, case);
        assert!(
            os.output.same_as(&ls.output),
            "{} {} B: libcsp and ours differ:\nlibcsp {:?}\nours   {:?}",
            case.op.name(),
            case.len,
            ls.output,
            os.output
        );
        series.push([
            Series {
                iters: li,
                ns: Vec::new(),
            },
            Series {
                iters: oi,
                ns: Vec::new(),
            },
        ]);
    }
    let mut buffers: Vec<Series> = BUFFER_LENS
        .iter()
        .map(|&len| Series {
            iters: calibrate_buffer(len),
            ns: Vec::new(),
        })
        .collect();

    // The rounds, interleaved; the order of the sides alternates.
    for round in 0..ROUNDS {
        let order = if round % 2 == 0 {
            [Side::Libcsp, Side::Ours]
        } else {
            [Side::Ours, Side::Libcsp]
        };
        for (case, pair) in CASES.iter().zip(series.iter_mut()) {
            for side in order {
                let slot = &mut pair[usize::from(side == Side::Ours)];
                let s = measure(side, *case, slot.iters);
                slot.ns.push(s.ns_per_iter());
            }
        }
        for (&len, b) in BUFFER_LENS.iter().zip(buffers.iter_mut()) {
            let ns = m6p_libcsp_compare::libcsp_buffer_cycle(len, b.iters).expect("buffer cycle");
            b.ns.push(ns as f64 / b.iters as f64);
        }
    }

    // The report.
    let mut table = String::new();
    let _ = writeln!(
        table,
        "libcsp 1.4 vs m6p-csp: ns per operation, median of {ROUNDS} interleaved rounds (min-max), ~{} ms per measurement; load average {load_before} before, {} after",
        TARGET.as_millis(),
        load_average()
    );
    let _ = writeln!(
        table,
        "{:<14} {:>5}  {:>30}  {:>30}  {:>11}  {:>15}",
        "op", "bytes", "libcsp ns (min-max)", "ours ns (min-max)", "libcsp/ours", "iters lib/ours"
    );
    let cell = |s: &Series| format!("{:.1} ({:.1}-{:.1})", s.median(), s.min(), s.max());
    let mut cases_json = Vec::new();
    for (case, [lib, ours]) in CASES.iter().zip(&series) {
        let ratio = lib.median() / ours.median();
        let _ = writeln!(
            table,
            "{:<14} {:>5}  {:>30}  {:>30}  {:>10.1}x  {:>15}",
            case.op.name(),
            case.len,
            cell(lib),
            cell(ours),
            ratio,
            format!("{}/{}", lib.iters, ours.iters)
        );
        cases_json.push(json!({
            "op": case.op.name(),
            "bytes": case.len,
            "libcsp": lib.json(),
            "ours": ours.json(),
            "ratio_libcsp_over_ours": ratio,
        }));
    }
    let mut buffer_json = Vec::new();
    let _ = write!(
        table,
        "libcsp buffer get+copy+free alone (inside its kiss_encode and cfp_fragment rows):"
    );
    for (&len, b) in BUFFER_LENS.iter().zip(&buffers) {
        let _ = write!(table, " {len} B {}", cell(b));
        buffer_json.push(json!({"bytes": len, "libcsp": b.json()}));
    }
    let _ = writeln!(table);
    let mut acceptance_json = Vec::new();
    let mut all_ok = true;
    let _ = write!(table, "acceptance (ratio of medians):");
    for (op, len, least) in ACCEPTANCE {
        let Some((_, [lib, ours])) = CASES
            .iter()
            .zip(&series)
            .find(|(c, _)| c.op == op && c.len == len)
        else {
            continue;
        };
        let ratio = lib.median() / ours.median();
        let ok = ratio >= least;
        all_ok &= ok;
        let _ = write!(
            table,
            " {} {len} B >= {least}x: {ratio:.1}x {};",
            op.name(),
            if ok { "ok" } else { "FAIL" }
        );
        acceptance_json.push(json!({
            "op": op.name(),
            "bytes": len,
            "least_ratio": least,
            "ratio": ratio,
            "ok": ok,
        }));
    }
    let _ = writeln!(
        table,
        " {}",
        if all_ok { "all hold" } else { "NOT ALL HOLD" }
    );

    if json_out {
        eprint!("{table}");
        let report = json!({
            "bench": "vs_libcsp",
            "unit": "ns per operation",
            "rounds": ROUNDS,
            "target_ms_per_measurement": TARGET.as_millis() as u64,
            "cases": cases_json,
            "libcsp_buffer_cycle": buffer_json,
            "acceptance": acceptance_json,
            "acceptance_all_hold": all_ok,
        });
        println!("{report}");
    } else {
        print!("{table}");
    }
}
