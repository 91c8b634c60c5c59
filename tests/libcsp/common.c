/* Shared setup of the libcsp 1.4 test programs: see common.h for what it offers.
 *
 * libcsp 1.4 facts this file relies on (checked against its source, libcsp-1.4.tar.gz):
 * - Order: csp_buffer_init, csp_init(addr), the interface, the routes, csp_route_start_task.
 *   csp_init routes our own address and, until we change it, the default route to the
 *   loopback interface.
 * - Buffers: the KISS receiver takes a buffer of the interface MTU (256 data bytes) for
 *   every frame, the ZMQ receiver one of 256, so the buffer data size must be at least 256;
 *   a packet sent with the CRC flag over KISS grows by 4 (CSP CRC32) + 4 (KISS CRC32) in
 *   place. BUF_DATA_SIZE = 300 leaves room for both.
 * - The static routing table (rtable/csp_rtable_static.c) has one entry per host address
 *   plus a default route; each entry is (interface, next-hop "mac"). CSP_NODE_MAC (255)
 *   means "the destination itself".
 * - Logging goes to stdout with printf unless a hook is set (csp_debug_hook_set); we send
 *   it to stderr so that stdout stays machine-parsable.
 * - CMP ident copies csp_get_hostname()/csp_get_model() with strncpy: both must be set or
 *   a node answering CMP ident dereferences NULL.
 */
#include "common.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <csp/csp.h>
#include <csp/csp_rtable.h>
#include <csp/drivers/usart.h>
#include <csp/interfaces/csp_if_can.h>
#include <csp/interfaces/csp_if_kiss.h>
#ifdef HAVE_ZMQ
#include <csp/interfaces/csp_if_zmqhub.h>
#endif

/* libcsp buffers: count and data size (see the comment at the top). */
#define BUF_COUNT 100
#define BUF_DATA_SIZE 300

/* The M6P addresses the CAN routes need (crates/twin/src/network.rs, ICD 1.7). */
#define ADDR_COMM1 1
#define ADDR_PC 6
#define ADDR_PAYLOAD_MIN 12
#define ADDR_PAYLOAD_MAX 15
#define ADDR_GROUND_MIN 16
#define ADDR_GROUND_MAX 20

const char common_usage[] =
	"interface (exactly one):\n"
	"  --kiss PATH       KISS over a serial device or pty (libcsp's Linux usart driver)\n"
	"  --kiss-baud N     its baud rate (default 500000; a pty ignores it)\n"
	"  --zmq HOST        libcsp's ZMQ hub interface (tcp://HOST:6000 out, tcp://HOST:7000 in)\n"
	"  --can IFNAME      CAN (CFP) through libcsp's SocketCAN driver, e.g. vcan0\n"
	"common:\n"
	"  --addr N          our CSP address, 0-30\n"
	"  --debug           also libcsp's INFO and PACKET log lines (stderr)\n"
	"  --quiet-csp       none of libcsp's log lines, not even errors and warnings\n";

void common_opts_init(struct common_opts *o) {
	memset(o, 0, sizeof(*o));
	o->kind = IFACE_NONE;
	o->kiss_baud = 500000;
	o->addr = -1;
}

int common_parse_long(const char *s, long lo, long hi, long *out) {
	char *end = NULL;
	if (s == NULL || *s == '\0')
		return -1;
	errno = 0;
	long v = strtol(s, &end, 10);
	if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi)
		return -1;
	*out = v;
	return 0;
}

/* Selects an interface, refusing a second one. */
static int set_iface(struct common_opts *o, enum iface_kind k, const char *opt) {
	if (o->kind != IFACE_NONE && o->kind != k) {
		fprintf(stderr, "%s: only one of --kiss, --zmq, --can may be given\n", opt);
		return -1;
	}
	o->kind = k;
	return 0;
}

int common_parse_opt(int argc, char **argv, int *i, struct common_opts *o) {
	const char *a = argv[*i];
	const char *val = (*i + 1 < argc) ? argv[*i + 1] : NULL;
	long v;
	int needs_value = !strcmp(a, "--kiss") || !strcmp(a, "--kiss-baud") || !strcmp(a, "--zmq") ||
			  !strcmp(a, "--can") || !strcmp(a, "--addr");
	if (needs_value && val == NULL) {
		fprintf(stderr, "%s needs a value\n", a);
		return -1;
	}
	if (!strcmp(a, "--kiss")) {
		if (set_iface(o, IFACE_KISS, a) < 0)
			return -1;
		o->kiss_dev = val;
	} else if (!strcmp(a, "--kiss-baud")) {
		if (common_parse_long(val, 1, 4000000, &v) < 0) {
			fprintf(stderr, "--kiss-baud: not a baud rate: %s\n", val);
			return -1;
		}
		o->kiss_baud = (unsigned)v;
	} else if (!strcmp(a, "--zmq")) {
#ifndef HAVE_ZMQ
		fprintf(stderr, "--zmq: built without libzmq (install libzmq3-dev and rebuild)\n");
		return -1;
#endif
		if (set_iface(o, IFACE_ZMQ, a) < 0)
			return -1;
		o->zmq_host = val;
	} else if (!strcmp(a, "--can")) {
		if (set_iface(o, IFACE_CAN, a) < 0)
			return -1;
		o->can_ifname = val;
	} else if (!strcmp(a, "--addr")) {
		if (common_parse_long(val, 0, CSP_ID_HOST_MAX - 1, &v) < 0) {
			fprintf(stderr, "--addr: not a CSP address 0-%d: %s\n", CSP_ID_HOST_MAX - 1, val);
			return -1;
		}
		o->addr = (int)v;
	} else if (!strcmp(a, "--debug")) {
		o->debug = 1;
		return 1;
	} else if (!strcmp(a, "--quiet-csp")) {
		o->quiet_csp = 1;
		return 1;
	} else {
		return 0;
	}
	*i += 1; /* the value */
	return 1;
}

int common_check_opts(const struct common_opts *o) {
	if (o->kind == IFACE_NONE) {
		fprintf(stderr, "no interface: give one of --kiss PATH, --zmq HOST, --can IFNAME\n");
		return -1;
	}
	if (o->addr < 0) {
		fprintf(stderr, "no address: give --addr N\n");
		return -1;
	}
	return 0;
}

uint64_t common_now_us(void) {
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

void common_hex(const uint8_t *data, size_t n, char *out) {
	static const char digits[] = "0123456789abcdef";
	for (size_t i = 0; i < n; i++) {
		out[2 * i] = digits[data[i] >> 4];
		out[2 * i + 1] = digits[data[i] & 0xf];
	}
	out[2 * n] = '\0';
}

static int hexval(char c) {
	if (c >= '0' && c <= '9')
		return c - '0';
	if (c >= 'a' && c <= 'f')
		return c - 'a' + 10;
	if (c >= 'A' && c <= 'F')
		return c - 'A' + 10;
	return -1;
}

int common_unhex(const char *hex, uint8_t *out, size_t max) {
	size_t n = 0;
	int hi = -1;
	for (const char *p = hex; *p; p++) {
		if (*p == ' ' || *p == '_' || *p == ':')
			continue;
		int v = hexval(*p);
		if (v < 0)
			return -1;
		if (hi < 0) {
			hi = v;
		} else {
			if (n >= max)
				return -1;
			out[n++] = (uint8_t)(hi << 4 | v);
			hi = -1;
		}
	}
	return hi < 0 ? (int)n : -1;
}

void common_quote(const uint8_t *data, size_t n, int stop_at_nul, char *out, size_t outsz) {
	size_t o = 0;
	if (outsz < 3) {
		if (outsz)
			out[0] = '\0';
		return;
	}
	out[o++] = '"';
	for (size_t i = 0; i < n; i++) {
		uint8_t c = data[i];
		char tmp[5];
		if (c == 0 && stop_at_nul)
			break;
		if (c == '\\' || c == '"')
			snprintf(tmp, sizeof tmp, "\\%c", c);
		else if (c == '\n')
			snprintf(tmp, sizeof tmp, "\\n");
		else if (c == '\r')
			snprintf(tmp, sizeof tmp, "\\r");
		else if (c == '\t')
			snprintf(tmp, sizeof tmp, "\\t");
		else if (c < 0x20 || c >= 0x7f)
			snprintf(tmp, sizeof tmp, "\\x%02x", c);
		else
			snprintf(tmp, sizeof tmp, "%c", c);
		size_t l = strlen(tmp);
		if (o + l + 2 > outsz)
			break; /* truncated: keep room for the closing quote */
		memcpy(out + o, tmp, l);
		o += l;
	}
	out[o++] = '"';
	out[o] = '\0';
}

/* ---------------------------------------------------------------------------------------
 * libcsp's log, to stderr. */

static int debug_enabled;

static void log_hook(csp_debug_level_t level, const char *format, va_list args) {
	static const char *names[] = {"ERROR", "WARN", "INFO", "BUFFER", "PACKET", "PROTOCOL", "LOCK"};
	const char *name = (unsigned)level < sizeof(names) / sizeof(names[0]) ? names[level] : "?";
	char msg[512];
	vsnprintf(msg, sizeof msg, format, args);
	fprintf(stderr, "csp %s: %s\n", name, msg);
}

/* ---------------------------------------------------------------------------------------
 * KISS over libcsp's Linux usart driver, wired as libcsp 1.4's examples/kiss.c does:
 * usart_init opens the device and starts a receive thread; csp_kiss_init registers the
 * interface with usart_putc as its byte writer; usart_set_callback hands every chunk read
 * to our callback, which passes it to csp_kiss_rx. */

static csp_iface_t kiss_iface;
static csp_kiss_handle_t kiss_handle;
static volatile unsigned long kiss_discarded;
static void (*link_closed_handler)(void);
static pthread_t main_thread;
static int started;

unsigned long common_kiss_discarded(void) {
	return kiss_discarded;
}

void common_set_link_closed_handler(void (*fn)(void)) {
	link_closed_handler = fn;
}

static void link_closed(void) {
	if (link_closed_handler != NULL)
		link_closed_handler(); /* does not return */
	fflush(stderr);
	printf("fail link reason=device_closed\n");
	fflush(stdout);
	_exit(1);
}

/* Bytes outside KISS frames. libcsp's example passes usart_insert, which printf()s them to
 * stdout; we only count them (they are reported on stderr at exit). */
static void kiss_discard(char c, void *pxTaskWoken) {
	(void)c;
	(void)pxTaskWoken;
	kiss_discarded++;
}

/* libcsp 1.4's usart receive thread (usart_linux.c serial_rx_thread) keeps the result of
 * read() in an *unsigned* int: when the pty's other side closes, read() fails with EIO
 * (-1), the `length <= 0` test does not catch it, and the callback gets len = -1, with
 * which csp_kiss_rx would walk 4 GB past its buffer (a SIGSEGV within a moment). So a
 * non-positive length here means "the device is gone": we stop cleanly instead. (read()
 * returning 0, at the end of a file, makes the driver call exit(1) itself: see
 * exit_watch below.) */
static void kiss_usart_rx(uint8_t *buf, int len, void *pxTaskWoken) {
	if (len <= 0)
		link_closed();
	csp_kiss_rx(&kiss_iface, buf, len, pxTaskWoken);
}

/* exit() called from a thread other than main (libcsp's usart driver on end of file) is
 * treated as the link closing. */
static void exit_watch(void) {
	if (started && !pthread_equal(pthread_self(), main_thread))
		link_closed();
}

/* Runs fn(arg) with stdout pointed at stderr: some libcsp init functions printf chatter
 * ("INIT ZMQ with addr ...", "Failed to open ...") that must not reach our stdout. */
static int with_stdout_on_stderr(int (*fn)(void *), void *arg) {
	fflush(stdout);
	int saved = dup(STDOUT_FILENO);
	if (saved >= 0)
		dup2(STDERR_FILENO, STDOUT_FILENO);
	int r = fn(arg);
	fflush(stdout);
	if (saved >= 0) {
		dup2(saved, STDOUT_FILENO);
		close(saved);
	}
	return r;
}

static int do_usart_init(void *arg) {
	usart_init((struct usart_conf *)arg); /* returns nothing; we opened the device first */
	return 0;
}

static int start_kiss(const struct common_opts *o) {
	/* usart_init prints and returns silently if it cannot open the device: try first. */
	int probe = open(o->kiss_dev, O_RDWR | O_NOCTTY | O_NONBLOCK);
	if (probe < 0) {
		fprintf(stderr, "--kiss: cannot open %s: %s\n", o->kiss_dev, strerror(errno));
		return -1;
	}
	close(probe);
	static struct usart_conf conf;
	memset(&conf, 0, sizeof conf);
	conf.device = o->kiss_dev;
	conf.baudrate = o->kiss_baud;
	conf.databits = 8;
	conf.stopbits = 1;
	with_stdout_on_stderr(do_usart_init, &conf);
	csp_kiss_init(&kiss_iface, &kiss_handle, usart_putc, kiss_discard, "KISS");
	usart_set_callback(kiss_usart_rx);
	/* Routes: the KISS link is point to point; whatever is behind it (the twin) routes
	 * onwards. Every destination but our own address (loopback, set by csp_init) goes out
	 * on it; the next-hop mac means nothing to KISS. */
	if (csp_route_set(CSP_DEFAULT_ROUTE, &kiss_iface, CSP_NODE_MAC) != CSP_ERR_NONE)
		return -1;
	return 0;
}

#ifdef HAVE_ZMQ
struct zmq_args {
	uint8_t addr;
	char *host;
};

static int do_zmq_init(void *arg) {
	struct zmq_args *z = arg;
	return csp_zmqhub_init((char)z->addr, z->host);
}
#endif

static int start_zmq(const struct common_opts *o) {
#ifdef HAVE_ZMQ
	/* csp_zmqhub_init subscribes to our own address byte: every message on the hub starts
	 * with the next hop's address (csp_rtable_find_mac, or the destination when the route
	 * says CSP_NODE_MAC), and we receive those that start with ours. */
	static struct zmq_args z;
	z.addr = (uint8_t)o->addr;
	z.host = strdup(o->zmq_host);
	if (z.host == NULL || with_stdout_on_stderr(do_zmq_init, &z) != CSP_ERR_NONE) {
		fprintf(stderr, "--zmq: csp_zmqhub_init failed\n");
		return -1;
	}
	/* Routes: the hub is one shared medium; every destination but our own address goes to
	 * it, addressed to the destination itself (CSP_NODE_MAC). A bridge on the hub that
	 * serves several addresses subscribes to each of them. */
	if (csp_route_set(CSP_DEFAULT_ROUTE, &csp_if_zmqhub, CSP_NODE_MAC) != CSP_ERR_NONE)
		return -1;
	return 0;
#else
	(void)o;
	fprintf(stderr, "--zmq: built without libzmq\n");
	return -1;
#endif
}

static int start_can(const struct common_opts *o) {
	/* libcsp 1.4 has no csp_can_socketcan_init (that is 1.5's); its CAN interface is
	 * csp_can_init(mode, conf), which opens the SocketCAN interface conf.ifc. Masked mode:
	 * the socket only receives CFP frames whose destination is our address. */
	static struct csp_can_config conf;
	static char ifname[64];
	snprintf(ifname, sizeof ifname, "%s", o->can_ifname);
	conf.bitrate = 1000000; /* informational: SocketCAN interfaces have theirs set by `ip link` */
	conf.clock_speed = 0;
	conf.ifc = ifname;
	if (csp_can_init(CSP_CAN_MASKED, &conf) != CSP_ERR_NONE) {
		fprintf(stderr, "--can: csp_can_init(%s) failed\n", o->can_ifname);
		return -1;
	}
	/* Routes, as the M6P's (crates/twin/src/network.rs, ICD 1.7). On a CAN bus the route's
	 * mac is the CFP destination of the frames: the next hop, which must be on the bus.
	 *
	 * On the payload bus (our address 12-15): the other payloads directly; everything
	 * else (the platform, the ground) through the payload controller, PC 6, which sits on
	 * both buses.
	 *
	 * On the main bus (any other address): the platform nodes (COMM 1/2, FC 3, EPS 4,
	 * ECU 5, PC 6, and any other main-bus address) directly; payloads 12-15 through the
	 * PC 6; ground stations 16-20 through the primary COMM 1, whose radio is the link to
	 * the ground. */
	int on_payload_bus = o->addr >= ADDR_PAYLOAD_MIN && o->addr <= ADDR_PAYLOAD_MAX;
	int r = 0;
	if (on_payload_bus) {
		r |= csp_route_set(CSP_DEFAULT_ROUTE, &csp_if_can, ADDR_PC);
		for (int a = ADDR_PAYLOAD_MIN; a <= ADDR_PAYLOAD_MAX; a++)
			if (a != o->addr)
				r |= csp_route_set(a, &csp_if_can, CSP_NODE_MAC);
	} else {
		r |= csp_route_set(CSP_DEFAULT_ROUTE, &csp_if_can, CSP_NODE_MAC);
		for (int a = ADDR_PAYLOAD_MIN; a <= ADDR_PAYLOAD_MAX; a++)
			r |= csp_route_set(a, &csp_if_can, ADDR_PC);
		for (int a = ADDR_GROUND_MIN; a <= ADDR_GROUND_MAX; a++)
			if (a != o->addr)
				r |= csp_route_set(a, &csp_if_can, ADDR_COMM1);
	}
	return r == CSP_ERR_NONE ? 0 : -1;
}

static const char *iface_name = "none";

const char *common_iface_name(void) {
	return iface_name;
}

int common_start(const struct common_opts *o, const char *hostname) {
	main_thread = pthread_self();
	atexit(exit_watch);

	/* libcsp's log to stderr; ERROR and WARN are on by default in csp_debug.c. */
	debug_enabled = o->debug;
	csp_debug_hook_set(log_hook);
	if (o->quiet_csp) {
		csp_debug_set_level(CSP_ERROR, false);
		csp_debug_set_level(CSP_WARN, false);
	}
	if (o->debug) {
		csp_debug_set_level(CSP_INFO, true);
		csp_debug_set_level(CSP_PACKET, true);
	}

	if (csp_buffer_init(BUF_COUNT, BUF_DATA_SIZE) != CSP_ERR_NONE) {
		fprintf(stderr, "csp_buffer_init failed\n");
		return -1;
	}
	/* CMP ident answers with these (they must not be NULL). */
	static char host[CSP_HOSTNAME_LEN];
	static char model[] = "m6p-twin libcsp-1.4 test";
	snprintf(host, sizeof host, "%s", hostname);
	csp_set_hostname(host);
	csp_set_model(model);
	if (csp_init((uint8_t)o->addr) != CSP_ERR_NONE) {
		fprintf(stderr, "csp_init failed\n");
		return -1;
	}

	int r = -1;
	switch (o->kind) {
	case IFACE_KISS:
		iface_name = "KISS";
		r = start_kiss(o);
		break;
	case IFACE_ZMQ:
		iface_name = "ZMQHUB";
		r = start_zmq(o);
		break;
	case IFACE_CAN:
		iface_name = "CAN";
		r = start_can(o);
		break;
	case IFACE_NONE:
		break;
	}
	if (r < 0)
		return -1;

	/* The router task: it takes packets from the interfaces' input queue, routes those
	 * not for us, and hands ours to sockets and connections (csp_route.c). Stack size and
	 * priority are ignored on POSIX. */
	if (csp_route_start_task(0, 0) != CSP_ERR_NONE) {
		fprintf(stderr, "csp_route_start_task failed\n");
		return -1;
	}
	started = 1;
	if (debug_enabled) {
		fflush(stdout);
		fprintf(stderr, "csp: address %d on %s\n", o->addr, iface_name);
	}
	return 0;
}
