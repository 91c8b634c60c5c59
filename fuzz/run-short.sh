#!/usr/bin/env bash
# A short fuzz pass over every target: fuzz/run-short.sh [SECONDS_PER_TARGET] (default 20),
# or fuzz/run-short.sh --build-only (what .ci/run starts beside the tests).
#
# Builds all targets (`cargo +nightly fuzz build -O -a -s none`: optimised at opt-level 1,
# which builds in 6 min instead of 8 on a 2-core machine, with debug assertions and overflow
# checks on, no sanitizer: the workspace denies unsafe code), then runs each for
# the given time on a temporary copy of its committed corpus (fuzz/corpus/<target>/ is never
# grown; minimise and commit new seeds by hand), one target per core at a time (FUZZ_JOBS
# sets how many). Prints per target the executions done and the rate; exits non-zero naming
# every target that crashed and its artifact (fuzz/artifacts/<target>/). Without a nightly
# toolchain it says so and exits 0.
set -uo pipefail

build_only=0
if [ "${1:-}" = --build-only ]; then
    build_only=1
    shift
fi
secs=${1:-20}
case $secs in
'' | *[!0-9]*)
    echo "usage: $0 [SECONDS_PER_TARGET]" >&2
    exit 2
    ;;
esac
# One target per core at a time (libFuzzer runs on one thread): on CI's two cores the pass
# takes half the wall time (fuzz/README.md), and each target still gets its seconds on a core.
jobs_max=${FUZZ_JOBS:-$(nproc 2>/dev/null || echo 1)}
case $jobs_max in
'' | *[!0-9]* | 0*)
    echo "FUZZ_JOBS must be a number of targets at a time, 1 or more (not '$jobs_max')" >&2
    exit 2
    ;;
esac
fuzz=$(cd "$(dirname "$0")" && pwd)
cd "$fuzz" || exit 1

if ! cargo +nightly --version >/dev/null 2>&1; then
    echo "fuzz: no nightly toolchain here; the fuzz pass was not run"
    exit 0
fi
if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
    echo "fuzz: installing cargo-fuzz"
    if ! cargo install cargo-fuzz --locked; then
        echo "fuzz: cargo-fuzz could not be installed; the fuzz pass was not run" >&2
        exit 1
    fi
fi

flags=(-O -a -s none)
# A short pass is mostly the committed corpus run once, for which opt-level 1 is fast enough,
# and it saves a quarter of the build. Long runs (fuzz/README.md) keep the profile's 3.
export CARGO_PROFILE_RELEASE_OPT_LEVEL=${CARGO_PROFILE_RELEASE_OPT_LEVEL:-1}
if ! nice -n 19 cargo +nightly fuzz build "${flags[@]}"; then
    echo "fuzz: the fuzz targets do not build" >&2
    exit 1
fi
if [ "$build_only" = 1 ]; then
    echo "fuzz: every target built"
    exit 0
fi

work=$(mktemp -d)
# Stopped or ended, the script leaves no fuzzer behind.
trap 'kill $(jobs -p) 2>/dev/null; wait; rm -rf "$work"' EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# Each target writes its own log and exit code; the table is printed in the targets' order.
run_one() {
    local t=$1
    mkdir -p "$work/corpus/$t" "$fuzz/artifacts/$t"
    if [ -d "corpus/$t" ]; then
        cp -R "corpus/$t/." "$work/corpus/$t/"
    fi
    # Stopped (TERM from the script's exit, or a Ctrl-C, which `timeout` in its own process
    # group does not see), it stops its fuzzer and waits for it: timeout passes the signal on.
    local pid=
    trap '[ -n "$pid" ] && kill "$pid" 2>/dev/null && wait "$pid"; exit 143' INT TERM
    # -timeout: one input running longer than 60 s is a hang, reported like a crash.
    timeout $((secs + 300)) nice -n 19 cargo +nightly fuzz run "${flags[@]}" "$t" "$work/corpus/$t" -- \
        -max_total_time="$secs" -print_final_stats=1 -timeout=60 \
        -artifact_prefix="$fuzz/artifacts/$t/" >"$work/$t.log" 2>&1 &
    pid=$!
    wait "$pid"
    echo $? >"$work/$t.rc"
}
if ! targets=$(cargo +nightly fuzz list) || [ -z "$targets" ]; then
    echo "fuzz: cargo fuzz list named no target" >&2
    exit 1
fi
for t in $targets; do
    while [ "$(jobs -rp | wc -l)" -ge "$jobs_max" ]; do
        wait -n
    done
    run_one "$t" &
done
wait

crashed=()
printf '%-16s %12s %10s  %s\n' target executions exec/s result
for t in $targets; do
    log=$work/$t.log
    rc=$(cat "$work/$t.rc" 2>/dev/null || echo 1)
    execs=$(sed -n 's/^stat::number_of_executed_units: *\([0-9]*\).*/\1/p' "$log" | tail -1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *\([0-9]*\).*/\1/p' "$log" | tail -1)
    if [ "$rc" -eq 0 ]; then
        result=ok
    else
        artifact=$(sed -n 's/.*Test unit written to \([^ ]*\).*/\1/p' "$log" | tail -1)
        result="CRASH (exit $rc) ${artifact:-no artifact written}"
        crashed+=("$t: ${artifact:-exit $rc, no artifact (see the log above)}")
    fi
    printf '%-16s %12s %10s  %s\n' "$t" "${execs:-?}" "${rate:-?}" "$result"
    if [ "$rc" -ne 0 ]; then
        echo "---- $t: the end of libFuzzer's output"
        tail -n 60 "$log"
        echo "----"
    fi
done

if [ ${#crashed[@]} -gt 0 ]; then
    echo "fuzz: ${#crashed[@]} target(s) crashed:" >&2
    for c in "${crashed[@]}"; do
        echo "  $c" >&2
    done
    echo "fuzz: reproduce with: cargo +nightly fuzz run ${flags[*]} <target> <artifact>" >&2
    exit 1
fi
echo "fuzz: every target ran ${secs} s without a crash"
