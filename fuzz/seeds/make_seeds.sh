#!/usr/bin/env bash
# Regenerate the committed seed corpora fuzz/corpus/<target>/ (see seeds/make_seeds.rs for
# what each seed is and where it comes from).
#
# 1. Runs a few scenarios of scenarios/ briefly with the twin and records them (MCAP).
# 2. Exports their CAN traffic (`m6p-twin inspect --csv /can/main/frames`, `/can/payload/frames`).
# 3. Runs the generator (`cargo +nightly run --example make_seeds`), which also reads the libcsp
#    1.4 golden vectors (../shared/vectors/libcsp-1.4), the Vallado TLEs
#    (../shared/reference/sgp4_vallado_tles.csv) and scenarios/*.toml.
#
# shared/ (the vectors and references): $M6P_SHARED, else ../shared beside the repository.
# The twin binary: $M6P_TWIN, else target/release/m6p-twin of the workspace, else one built
# here into fuzz/target-bin (niced, one job: the workspace's target/ is left alone).
# Recordings depend on the twin's version; the corpus is a starting point, not a fixture:
# regenerate it when the formats change, and review the diff before committing.
set -euo pipefail

fuzz=$(cd "$(dirname "$0")/.." && pwd)
root=$(cd "$fuzz/.." && pwd)
shared=${M6P_SHARED:-$root/../shared}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

twin=${M6P_TWIN:-$root/target/release/m6p-twin}
if [ ! -x "$twin" ]; then
    echo "make_seeds: building the twin into fuzz/target-bin"
    CARGO_TARGET_DIR="$fuzz/target-bin" nice -n 19 cargo build --release -j1 \
        --manifest-path "$root/Cargo.toml" -p m6p-twin
    twin=$fuzz/target-bin/release/m6p-twin
fi

# name, scenario, simulated duration (cut short: only the start's traffic is needed).
record() {
    local name=$1 scenario=$2 duration=$3
    # A cut run fails its expectations: its exit status says nothing here.
    nice -n 19 "$twin" run "$root/scenarios/$scenario.toml" --duration "$duration" \
        --record "$work/$name.mcap" >"$work/$name.log" 2>&1 || true
    if [ ! -s "$work/$name.mcap" ]; then
        echo "make_seeds: $scenario did not record (see below)" >&2
        cat "$work/$name.log" >&2
        exit 1
    fi
}

can_args=()
for spec in default:default:10m fc-ports:fc-ports:5m ecu-burn:ecu-burn:2000s \
    eps-pc-off:eps-pc-off:400s node-faults:node-faults:5m pc-buffering:pc-buffering:1300s; do
    IFS=: read -r name scenario duration <<<"$spec"
    record "$name" "$scenario" "$duration"
    for bus in main payload; do
        "$twin" inspect "$work/$name.mcap" --csv "/can/$bus/frames" >"$work/$name-$bus.csv"
        if [ "$(wc -l <"$work/$name-$bus.csv")" -gt 1 ]; then
            can_args+=("--can-$bus" "$work/$name-$bus.csv")
        fi
    done
done

# Small recordings for the reader (whole, and their first 4 KiB).
record fc-ports-1s fc-ports 1s
record pc-polling-60s pc-polling 60s

cd "$fuzz"
CARGO_BUILD_JOBS=1 nice -n 19 cargo +nightly run --quiet --example make_seeds -- \
    --out "$fuzz/corpus" "${can_args[@]}" \
    --vectors "$shared/vectors/libcsp-1.4" --reference "$shared/reference" \
    --scenarios "$root/scenarios" \
    --recording "$work/fc-ports-1s.mcap" --recording "$work/pc-polling-60s.mcap"
du -sh "$fuzz/corpus"
