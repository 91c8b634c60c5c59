/* Shared setup of the libcsp 1.4 test programs (csp_client, csp_payload): command-line
 * options that pick the CSP interface, libcsp's initialisation in the order 1.4 needs it,
 * explicit routes, the router task, and a few output helpers.
 *
 * Interfaces (exactly one):
 *   --kiss PATH    KISS over a serial device or pty (libcsp's Linux usart driver), for
 *                  example a pty made by `socat PTY,link=PATH,raw,echo=0 TCP:HOST:PORT,nodelay`
 *                  in front of the twin's KISS/TCP server.
 *   --zmq HOST     libcsp's ZMQ hub interface: PUB connects to tcp://HOST:6000, SUB to
 *                  tcp://HOST:7000 (fixed by libcsp 1.4), subscribing to our own address.
 *   --can IFNAME   CAN with CFP through libcsp's SocketCAN driver (csp_can_init in 1.4).
 * and
 *   --addr N       our CSP address (0-30).
 *
 * Everything the programs print for a harness goes to stdout, one line per event; libcsp's
 * own log (and the chatter some of its interfaces printf at init) goes to stderr. */
#ifndef LIBCSP_TEST_COMMON_H
#define LIBCSP_TEST_COMMON_H

#include <stddef.h>
#include <stdint.h>

/* Which CSP interface the program uses. */
enum iface_kind { IFACE_NONE = 0, IFACE_KISS, IFACE_ZMQ, IFACE_CAN };

/* The options every program shares. */
struct common_opts {
	enum iface_kind kind;
	const char *kiss_dev;   /* --kiss PATH */
	unsigned kiss_baud;     /* --kiss-baud N (ignored by a pty; 500000 as libcsp's example) */
	const char *zmq_host;   /* --zmq HOST */
	const char *can_ifname; /* --can IFNAME */
	int addr;               /* --addr N; -1 until given (a program may preset a default) */
	int debug;              /* --debug: also libcsp's INFO and PACKET log lines (stderr) */
	int quiet_csp;          /* --quiet-csp: not even libcsp's ERROR/WARN lines */
};

/* Sets the defaults (no interface, address -1, baud 500000). */
void common_opts_init(struct common_opts *o);

/* If argv[*i] is one of the shared options, consumes it (and its value, advancing *i) and
 * returns 1; returns 0 if it is not a shared option, -1 (after a message on stderr) if it
 * is one but its value is missing or invalid. */
int common_parse_opt(int argc, char **argv, int *i, struct common_opts *o);

/* The usage text of the shared options, for a program's --help. */
extern const char common_usage[];

/* Checks that exactly one interface and an address were given; prints why not on stderr
 * and returns -1 if not, 0 if all is well. */
int common_check_opts(const struct common_opts *o);

/* Brings libcsp up: buffers, csp_init(addr), the interface, the routes (explained in
 * common.c), the router task. `hostname` is what CMP ident answers. Returns 0, or -1
 * after a message on stderr. */
int common_start(const struct common_opts *o, const char *hostname);

/* The name of the interface in use ("KISS", "ZMQHUB", "CAN"). */
const char *common_iface_name(void);

/* Called (from libcsp's usart receive thread, or from exit() when that thread calls it)
 * when the KISS device is closed under us: libcsp 1.4's usart driver would otherwise feed
 * the KISS decoder a length of -1 and crash (see common.c). The handler must not return
 * and must end the process with _exit() (it may run inside exit()); if none is set, the
 * program prints `fail link reason=device_closed` and _exit(1)s. */
void common_set_link_closed_handler(void (*fn)(void));

/* Bytes the KISS decoder discarded outside frames (libcsp calls the discard callback for
 * them; its example prints them to stdout, which would garble ours). */
unsigned long common_kiss_discarded(void);

/* Monotonic time in microseconds. */
uint64_t common_now_us(void);

/* Writes `n` bytes as lowercase hex (no separators) into `out` (2n+1 bytes). */
void common_hex(const uint8_t *data, size_t n, char *out);

/* Parses hex (even length, optional spaces/underscores/colons) into `out` (at most
 * `max` bytes). Returns the byte count or -1. */
int common_unhex(const char *hex, uint8_t *out, size_t max);

/* Writes `n` bytes as a double-quoted string with C escapes (\\ \" \n \r \t \xHH) into
 * `out` (at most `outsz` bytes, always terminated; truncated if too long). Stops at the
 * first NUL if `stop_at_nul`. */
void common_quote(const uint8_t *data, size_t n, int stop_at_nul, char *out, size_t outsz);

/* Parses a whole decimal number in [lo, hi]; returns 0 and stores it, or -1. */
int common_parse_long(const char *s, long lo, long hi, long *out);

#endif
