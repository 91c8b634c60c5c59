//! Inputs are bounded and honest: a scenario file over the documented size is refused at
//! once by its size (`/dev/zero` would otherwise be read until memory runs out), checking
//! is linear in the commands (a name searched among all before it makes a million
//! commands take over a minute), a TLE whose epoch is far from `start` is refused at
//! `check` naming the field (one 69 years old would fly the satellite at the Earth's centre),
//! and a run without an orbit records no made-up truth and `inspect` says `no orbit`.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::twin_process::{output_text as text, twin};

fn dir(name: &str) -> PathBuf {
    common::twin_process::test_dir("input-bounds", name)
}

/// A scenario of `n` pings to the FC, one a second, each named (so `after` and the
/// duplicate-name check have names to look up).
fn many_commands(d: &Path, n: u32) -> PathBuf {
    let mut s = String::from("name = \"many\"\nduration = \"2d\"\n");
    for i in 0..n {
        s.push_str(&format!(
            "\n[[commands]]\nname = \"c{i}\"\nat = \"{}s\"\nto = \"FC\"\nrequest = \"ping\"\n",
            i + 1
        ));
    }
    let p = d.join(format!("many-{n}.toml"));
    std::fs::write(&p, s).unwrap();
    p
}

#[test]
fn a_hundred_thousand_commands_check() {
    let d = dir("hundred-thousand");
    let s = many_commands(&d, 100_000);
    let out = twin().arg("check").arg(&s).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
}

/// Instructions of `m6p-twin check FILE` (cachegrind, deterministic).
fn check_instructions(file: &Path) -> u64 {
    let out = Command::new("valgrind")
        .args([
            "--tool=cachegrind",
            "--cache-sim=no",
            "--cachegrind-out-file=/dev/null",
        ])
        .arg(common::twin_process::twin_bin())
        .arg("check")
        .arg(file)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    let line = err
        .lines()
        .find(|l| l.contains("I") && l.contains("refs:"))
        .unwrap_or_else(|| panic!("no `I refs:` line in cachegrind's output:\n{err}"));
    line.rsplit(':')
        .next()
        .unwrap()
        .chars()
        .filter(char::is_ascii_digit)
        .collect::<String>()
        .parse()
        .unwrap()
}

/// Linear, measured the way performance is measured here (instructions, not seconds): the
/// cost of 10 k more commands is the same from 20 k to 30 k as from 10 k to 20 k, within a
/// fifth. Quadratic checking made the second step 5/3 of the first.
#[test]
#[cfg_attr(
    not(valgrind),
    ignore = "valgrind is not installed (apt-get install valgrind; CI installs it)"
)]
fn checking_costs_the_same_per_command_at_any_count() {
    let d = dir("linear");
    let [a, b, c] = [10_000, 20_000, 30_000].map(|n| check_instructions(&many_commands(&d, n)));
    let (first, second) = (b - a, c - b);
    let ratio = second as f64 / first as f64;
    eprintln!(
        "instructions: 10k {a}, 20k {b}, 30k {c}; per command {} then {} (ratio {ratio:.3})",
        first / 10_000,
        second / 10_000
    );
    assert!(
        (0.8..1.2).contains(&ratio),
        "10 k more commands cost {first} instructions from 10 k, {second} from 20 k"
    );
}

#[test]
fn a_file_that_never_ends_is_refused_by_its_size_at_once() {
    // Under a 1 GiB address-space limit: reading `/dev/zero` to the end cannot take the
    // machine with it, it fails with an allocation error instead of the size's message.
    let bin = common::twin_process::twin_bin();
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v 1048576; exec '{}' check /dev/zero",
            bin.display()
        ))
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(
        t.contains("/dev/zero") && t.contains("longer than 32 MiB"),
        "the refusal names the file and the limit: {t}"
    );
}

/// The TLE checksum of one line's first 68 characters.
fn with_checksum(line68: &str) -> String {
    let sum: u32 = line68
        .chars()
        .map(|c| match c {
            '-' => 1,
            c => c.to_digit(10).unwrap_or(0),
        })
        .sum();
    format!("{line68}{}", sum % 10)
}

fn tle_scenario(d: &Path, epoch: &str) -> PathBuf {
    let l1 = with_checksum(&format!(
        "1 99903U 26012AC  {epoch}  .00002345  00000-0  12345-3 0  999"
    ));
    let l2 = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
    let p = d.join(format!("tle-{epoch}.toml"));
    std::fs::write(
        &p,
        format!(
            "name = \"tle\"\nstart = \"2026-04-30T18:00:00Z\"\nduration = \"60s\"\n\n\
             [satellite]\ntle = [\n  \"{l1}\",\n  \"{l2}\",\n]\n"
        ),
    )
    .unwrap();
    p
}

#[test]
fn a_tle_far_from_start_is_refused_at_check_naming_the_field() {
    let d = dir("tle");
    // 1957-10-07: 69 years before `start`.
    let out = twin()
        .arg("check")
        .arg(tle_scenario(&d, "57280.00000000"))
        .output()
        .unwrap();
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(
        t.contains("satellite.tle") && t.contains("1957-10-07") && t.contains("days from `start`"),
        "the refusal names the field and the epoch: {t}"
    );
    // Twenty days before `start` flies (the FC's own limit is 30 days).
    let out = twin()
        .arg("check")
        .arg(tle_scenario(&d, "26100.75000000"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
}

#[test]
fn a_run_without_an_orbit_records_no_truth_and_inspect_says_so() {
    let d = dir("no-orbit");
    let s = d.join("no-orbit.toml");
    std::fs::write(&s, "name = \"no-orbit\"\nduration = \"30s\"\n").unwrap();
    let rec = d.join("no-orbit.mcap");
    let out = twin()
        .arg("run")
        .arg(&s)
        .arg("--record")
        .arg(&rec)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let out = twin().arg("inspect").arg(&rec).output().unwrap();
    let t = text(&out);
    assert!(out.status.success(), "{t}");
    assert!(t.contains("no orbit"), "{t}");
    for topic in ["/fc/truth/state", "/fc/truth/location", "/fc/adcs"] {
        let count = t
            .lines()
            .find(|l| l.split_whitespace().next() == Some(topic))
            .map_or(0, |l| {
                l.split_whitespace().last().unwrap().parse::<u64>().unwrap()
            });
        assert_eq!(count, 0, "{topic} recorded without an orbit:\n{t}");
    }
}
