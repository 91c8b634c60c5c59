#!/usr/bin/env bash
# Builds the libcsp 1.4 interoperability test programs of tests/libcsp/ into OUTDIR:
#   OUTDIR/libcsp/            libcsp 1.4 itself (libcsp.a, include/), by
#                             third_party/libcsp-1.4/build.sh
#   OUTDIR/bin/csp_client     checks against CSP nodes (ping, ident, ICD transactions ...)
#   OUTDIR/bin/csp_payload    a payload serving the PC's polling session
#   OUTDIR/bin/zmq_hub        a ZMQ hub (XSUB 6000 / XPUB 7000), when libzmq is installed
#   OUTDIR/bin/libcsp_payload examples/libcsp_payload.c, the example payload for users
#
# libcsp is the unmodified libcsp at its tag v1.4 (third_party/libcsp-1.4/libcsp-1.4.tar.gz,
# https://github.com/libcsp/libcsp), licensed under the LGPL-2.1 (its COPYING is in the
# archive); see third_party/libcsp-1.4/README.md. It is only linked into these test
# programs, never into the twin.
#
#   usage: tests/libcsp/build.sh OUTDIR
#
# Idempotent (everything is rebuilt each time, in a few seconds), stops at the first error.
# Our programs are compiled with -Wall -Wextra -Werror; libcsp with its own flags.
# The ZMQ interface (--zmq) is compiled in when zmq.h is installed (Debian: libzmq3-dev).
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
out=${1:?usage: build.sh OUTDIR}
mkdir -p "$out"
out=$(cd "$out" && pwd)
cc=${CC:-cc}

bash "$root/third_party/libcsp-1.4/build.sh" "$out/libcsp"

mkdir -p "$out/bin"
cflags=(-std=gnu99 -O2 -g -D_GNU_SOURCE -Wall -Wextra -Werror -I"$out/libcsp/include")
libs=("$out/libcsp/libcsp.a" -lpthread -lrt -lm)
zmq=no
if echo '#include <zmq.h>' | "$cc" -E -x c - >/dev/null 2>&1; then
  zmq=yes
  cflags+=(-DHAVE_ZMQ)
  libs+=(-lzmq)
fi

for prog in csp_client csp_payload; do
  "$cc" "${cflags[@]}" -o "$out/bin/$prog" "$here/$prog.c" "$here/common.c" "${libs[@]}"
done
# The example of examples/, built as its comment tells users to (without -DNO_ZMQ when
# libzmq is there).
example_flags=(-O2 -Wall -Wextra -Werror -I"$out/libcsp/include")
[ "$zmq" = yes ] || example_flags+=(-DNO_ZMQ)
"$cc" "${example_flags[@]}" -o "$out/bin/libcsp_payload" "$here/../../examples/libcsp_payload.c" "${libs[@]}"
if [ "$zmq" = yes ]; then
  "$cc" "${cflags[@]}" -o "$out/bin/zmq_hub" "$here/zmq_hub.c" -lzmq
else
  rm -f "$out/bin/zmq_hub"
fi

echo "libcsp test programs -> $out/bin (zmq: $zmq): $(ls "$out/bin" | tr '\n' ' ')"
