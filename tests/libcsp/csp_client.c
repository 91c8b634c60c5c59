/* csp_client: runs a list of checks against CSP nodes with the real libcsp 1.4, and prints
 * one machine-parsable line per check on stdout.
 *
 *   csp_client (--kiss PATH | --zmq HOST | --can IFNAME) --addr N [options] CHECK...
 *
 * Checks (NODE is a CSP address; `crc` asks for CSP's CRC32 flag on the connection):
 *   ping NODE SIZE [crc]          csp_ping with SIZE bytes (CSP_O_NONE or CSP_O_CRC32)
 *   ident NODE                    CMP ident (csp_cmp_ident): hostname, model, revision, date, time
 *   clock NODE                    CMP clock get (csp_cmp_clock with tv_sec 0): sec, nsec
 *   uptime NODE [crc]             a transaction to port CSP_UPTIME (6): 4 bytes
 *   ps NODE [crc]                 a request to port CSP_PS (2): its text replies until a gap
 *   memfree NODE [crc]            a transaction to port CSP_MEMFREE (3): 4 bytes
 *   buffree NODE [crc]            a transaction to port CSP_BUF_FREE (5): 4 bytes
 *   icd NODE PORT HEX LEN [crc]   a transaction sending HEX, expecting a reply of LEN bytes
 *   reserved NODE                 a 1-byte ping that must NOT be answered (ok on timeout)
 *   repeat N CHECK                CHECK N times: min/median/mean/max round trip
 *
 * Output, one line per check, fields separated by single spaces, strings double-quoted
 * with C escapes, byte strings in lowercase hex:
 *   ok|fail NAME DESC [reason=WHY] rtt_us=N DETAIL...
 * for example
 *   ok ping node=3 size=64 crc=0 rtt_us=2311 csp_ms=2
 *   fail ping node=3 size=64 crc=1 reason=timeout rtt_us=1000154
 *   ok icd node=3 port=10 req=01 expected=18 crc=0 rtt_us=2950 len=18 result=1 reply=0101...
 *   ok repeat icd node=3 port=10 req=01 expected=18 crc=0 n=50 passed=50 min_us=... median_us=... mean_us=... max_us=...
 * and at the end `summary checks=N ok=K fail=M`. Reasons: timeout (nothing within the
 * timeout), error (libcsp gave up before the timeout: no route, no buffer, bad echo),
 * length (a reply of another length), reply (a type/code that is not a CMP reply),
 * replied (`reserved` got an answer).
 *
 * Exit status: 0 if every check passed, 1 if any failed, 2 on a usage or setup error.
 *
 * Why uptime, memfree, buffree and ps are not libcsp's csp_uptime()/csp_memfree()/
 * csp_buf_free()/csp_ps(): in 1.4 those return nothing and printf their result, so they
 * cannot be checked. These checks do what those functions do (the same port, the same
 * request, csp_transaction's code), keep the reply, and decode it as they do (network
 * byte order). The round trips of ident and clock include csp_cmp()'s csp_transaction.
 */
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <csp/csp.h>
#include <csp/csp_cmp.h>
#include <csp/csp_endian.h>

#include "common.h"

/* The FC's telemetry commands and the whole reply data length each has on success
 * (`command | result | data`, 2 + the ICD size), from crates/twin/src/icd_lengths.rs
 * (IcdTable::for_run, the FC telemetry port: `ok::<fc::TmGen>()` ...), the sizes being the
 * node crate's wire types (crates/nodes-fc/src/wire.rs `Repr::LEN`: TmGen 16, TmAtp 60,
 * TmAcd 19, TmSens 70, TmRawSens 53, TmAll 177). The port is the run's `fc.ports.telemetry`,
 * 10 by default (nodes-fc wire::PORT_TELEMETRY); --fc-tm-port changes it. A failure reply
 * is `cmd 00`, 2 bytes (TMATP and TMALL fail without an orbit/TLE). */
static const struct {
	uint8_t cmd;
	const char *name;
	int reply_len;
} fc_telemetry[] = {
	{1, "TMGEN", 2 + 16},  {2, "TMATP", 2 + 60},     {3, "TMACD", 2 + 19},
	{4, "TMSENS", 2 + 70}, {5, "TMRAWSENS", 2 + 53}, {6, "TMALL", 2 + 177},
};
#define FC_ADDR 3
#define FC_TM_PORT_DEFAULT 10

/* Largest request or reply we handle: libcsp's buffers hold 300 data bytes (common.c);
 * csp_transaction_persistent copies a reply of any length into our buffer. */
#define MAX_REQ 256
#define REPLY_BUF 512

enum kind { K_PING, K_IDENT, K_CLOCK, K_UPTIME, K_PS, K_MEMFREE, K_BUFFREE, K_ICD, K_RESERVED };

static const char *kind_names[] = {
	[K_PING] = "ping",       [K_IDENT] = "ident",     [K_CLOCK] = "clock",
	[K_UPTIME] = "uptime",   [K_PS] = "ps",           [K_MEMFREE] = "memfree",
	[K_BUFFREE] = "buffree", [K_ICD] = "icd",         [K_RESERVED] = "reserved",
};

/* One check, as parsed from the command line. */
struct check {
	enum kind kind;
	int node;
	int size;     /* ping */
	int port;     /* icd */
	uint8_t req[MAX_REQ];
	int req_len;  /* icd */
	int expected; /* icd */
	int crc;
	int repeat;   /* 0: once; N: `repeat N` */
};

/* What running it gave. */
struct result {
	int ok;
	uint64_t rtt_us;
	const char *reason; /* NULL when ok */
	char detail[4096];  /* " key=value ..." */
};

static uint32_t timeout_ms = 1000;
static uint32_t ps_gap_ms = 200;
static unsigned total, passed, failed;

static void usage(FILE *f) {
	fprintf(f,
		"usage: csp_client (--kiss PATH | --zmq HOST | --can IFNAME) --addr N [options] CHECK...\n"
		"%s"
		"client:\n"
		"  --timeout MS      reply timeout of every check (default 1000)\n"
		"  --ps-gap MS       ps: wait this long for each further reply packet (default 200)\n"
		"  --gap MS          pause between checks (default 0)\n"
		"  --settle MS       pause after the interface starts (default 0; 500 with --zmq,\n"
		"                    for ZMQ's subscriptions to reach the hub)\n"
		"  --all-icd-fc      add one icd check per FC telemetry command (node 3, its reply\n"
		"                    length from crates/twin/src/icd_lengths.rs)\n"
		"  --fc-tm-port P    the FC telemetry port for --all-icd-fc (default 10)\n"
		"checks:\n"
		"  ping NODE SIZE [crc] | ident NODE | clock NODE | uptime NODE [crc] | ps NODE [crc]\n"
		"  memfree NODE [crc] | buffree NODE [crc] | icd NODE PORT HEX LEN [crc]\n"
		"  reserved NODE | repeat N CHECK\n",
		common_usage);
}

/* ---------------------------------------------------------------------------------------
 * Parsing. */

static int parse_num(const char *what, const char *s, long lo, long hi, int *out) {
	long v;
	if (common_parse_long(s, lo, hi, &v) < 0) {
		fprintf(stderr, "%s: not a number %ld-%ld: %s\n", what, lo, hi, s ? s : "(missing)");
		return -1;
	}
	*out = (int)v;
	return 0;
}

/* Parses one check from tok[*p...]; advances *p. */
static int parse_check(char **tok, int n, int *p, struct check *c, int allow_repeat) {
	memset(c, 0, sizeof *c);
#define ARG(k) ((*p + (k) < n) ? tok[*p + (k)] : NULL)
	const char *name = ARG(0);
	if (name == NULL)
		return -1;
	if (!strcmp(name, "repeat")) {
		int times;
		if (!allow_repeat) {
			fprintf(stderr, "repeat: cannot repeat a repeat\n");
			return -1;
		}
		if (parse_num("repeat N", ARG(1), 1, 1000000, &times) < 0)
			return -1;
		*p += 2;
		if (parse_check(tok, n, p, c, 0) < 0)
			return -1;
		c->repeat = times;
		return 0;
	}
	int k;
	for (k = 0; k <= K_RESERVED; k++)
		if (!strcmp(name, kind_names[k]))
			break;
	if (k > K_RESERVED) {
		fprintf(stderr, "unknown check: %s\n", name);
		return -1;
	}
	c->kind = (enum kind)k;
	if (parse_num(name, ARG(1), 0, CSP_ID_HOST_MAX, &c->node) < 0)
		return -1;
	int used = 2;
	if (c->kind == K_PING) {
		if (parse_num("ping SIZE", ARG(2), 0, 256, &c->size) < 0)
			return -1;
		used = 3;
	} else if (c->kind == K_ICD) {
		if (parse_num("icd PORT", ARG(2), 0, 63, &c->port) < 0)
			return -1;
		if (ARG(3) == NULL || (c->req_len = common_unhex(ARG(3), c->req, MAX_REQ)) < 0) {
			fprintf(stderr, "icd HEX: not hex bytes: %s\n", ARG(3) ? ARG(3) : "(missing)");
			return -1;
		}
		if (parse_num("icd LEN", ARG(4), 0, 256, &c->expected) < 0)
			return -1;
		used = 5;
	}
	int crc_allowed = c->kind != K_IDENT && c->kind != K_CLOCK && c->kind != K_RESERVED;
	const char *opt = ARG(used);
	if (crc_allowed && opt != NULL && strcmp(opt, "crc") == 0) {
		c->crc = 1;
		used++;
	}
	*p += used;
	return 0;
#undef ARG
}

/* The check's identifying fields. */
static void describe(const struct check *c, char *out, size_t sz) {
	char hex[2 * MAX_REQ + 1];
	switch (c->kind) {
	case K_PING:
		snprintf(out, sz, "node=%d size=%d crc=%d", c->node, c->size, c->crc);
		break;
	case K_ICD:
		common_hex(c->req, (size_t)c->req_len, hex);
		snprintf(out, sz, "node=%d port=%d req=%s expected=%d crc=%d", c->node, c->port,
			 c->req_len ? hex : "-", c->expected, c->crc);
		break;
	case K_UPTIME:
	case K_PS:
	case K_MEMFREE:
	case K_BUFFREE:
		snprintf(out, sz, "node=%d crc=%d", c->node, c->crc);
		break;
	default:
		snprintf(out, sz, "node=%d", c->node);
		break;
	}
}

/* ---------------------------------------------------------------------------------------
 * Running. */

static void add(struct result *r, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void add(struct result *r, const char *fmt, ...) {
	size_t l = strlen(r->detail);
	va_list ap;
	va_start(ap, fmt);
	vsnprintf(r->detail + l, sizeof r->detail - l, fmt, ap);
	va_end(ap);
}

/* A failure after `elapsed` µs with no reply: a timeout if libcsp waited (about) the
 * whole timeout, an error if it gave up earlier. */
static const char *no_reply_reason(uint64_t elapsed_us) {
	return elapsed_us + 50000 >= (uint64_t)timeout_ms * 1000 * 9 / 10 ? "timeout" : "error";
}

/* One request-reply exchange the way csp_transaction() does it, but on a connection
 * opened with our options (csp_transaction itself always uses CSP_TRANSACTION_SO, 0):
 * csp_connect, csp_transaction_persistent with inlen -1 (any reply length), csp_close.
 * Returns the reply length, or -1 for no reply. As in libcsp, a reply of 0 bytes cannot be
 * told from no reply (csp_transaction_persistent returns 0 for both). */
static int transact(int node, int port, int crc, const uint8_t *req, int req_len, uint8_t *reply,
		    uint64_t *rtt_us) {
	uint64_t t0 = common_now_us();
	csp_conn_t *conn = csp_connect(CSP_PRIO_NORM, (uint8_t)node, (uint8_t)port, timeout_ms,
				       crc ? CSP_O_CRC32 : CSP_O_NONE);
	int n = 0;
	if (conn != NULL) {
		n = csp_transaction_persistent(conn, timeout_ms, (void *)req, req_len, reply, -1);
		csp_close(conn);
	}
	*rtt_us = common_now_us() - t0;
	return n > 0 ? n : -1;
}

static void run_ping(const struct check *c, struct result *r) {
	uint64_t t0 = common_now_us();
	int ms = csp_ping((uint8_t)c->node, timeout_ms, (unsigned)c->size,
			  c->crc ? CSP_O_CRC32 : CSP_O_NONE);
	r->rtt_us = common_now_us() - t0;
	if (ms < 0) {
		r->reason = no_reply_reason(r->rtt_us);
		return;
	}
	r->ok = 1;
	add(r, " csp_ms=%d", ms);
}

static void run_reserved(const struct check *c, struct result *r) {
	uint64_t t0 = common_now_us();
	int ms = csp_ping((uint8_t)c->node, timeout_ms, 1, CSP_O_NONE);
	r->rtt_us = common_now_us() - t0;
	if (ms >= 0) {
		r->reason = "replied";
		add(r, " csp_ms=%d", ms);
		return;
	}
	if (strcmp(no_reply_reason(r->rtt_us), "timeout") != 0) {
		r->reason = "error"; /* libcsp could not even send it */
		return;
	}
	r->ok = 1;
	add(r, " outcome=timeout");
}

/* A CMP string field, quoted, up to its first NUL. */
static void add_cmp_string(struct result *r, const char *key, const char *s, size_t max) {
	char q[4 * 64 + 3];
	common_quote((const uint8_t *)s, max, 1, q, sizeof q);
	add(r, " %s=%s", key, q);
}

static void run_ident(const struct check *c, struct result *r) {
	struct csp_cmp_message msg;
	memset(&msg, 0, sizeof msg);
	uint64_t t0 = common_now_us();
	int e = csp_cmp_ident((uint8_t)c->node, timeout_ms, &msg);
	r->rtt_us = common_now_us() - t0;
	if (e != CSP_ERR_NONE) {
		/* csp_cmp's transaction wants exactly CMP_SIZE(ident) = 93 bytes; a reply of
		 * another length also ends here. */
		r->reason = no_reply_reason(r->rtt_us);
		return;
	}
	if (msg.type != CSP_CMP_REPLY || msg.code != CSP_CMP_IDENT) {
		r->reason = "reply";
		add(r, " type=%u code=%u", msg.type, msg.code);
		return;
	}
	r->ok = 1;
	add_cmp_string(r, "hostname", msg.ident.hostname, sizeof msg.ident.hostname);
	add_cmp_string(r, "model", msg.ident.model, sizeof msg.ident.model);
	add_cmp_string(r, "revision", msg.ident.revision, sizeof msg.ident.revision);
	add_cmp_string(r, "date", msg.ident.date, sizeof msg.ident.date);
	add_cmp_string(r, "time", msg.ident.time, sizeof msg.ident.time);
}

static void run_clock(const struct check *c, struct result *r) {
	struct csp_cmp_message msg;
	memset(&msg, 0, sizeof msg); /* tv_sec 0: read the clock, do not set it */
	uint64_t t0 = common_now_us();
	int e = csp_cmp_clock((uint8_t)c->node, timeout_ms, &msg);
	r->rtt_us = common_now_us() - t0;
	if (e != CSP_ERR_NONE) {
		r->reason = no_reply_reason(r->rtt_us);
		return;
	}
	if (msg.type != CSP_CMP_REPLY || msg.code != CSP_CMP_CLOCK) {
		r->reason = "reply";
		add(r, " type=%u code=%u", msg.type, msg.code);
		return;
	}
	r->ok = 1;
	/* The node answers in network byte order (csp_service_handler.c do_cmp_clock). */
	add(r, " sec=%" PRIu32 " nsec=%" PRIu32, csp_ntoh32(msg.clock.tv_sec),
	    csp_ntoh32(msg.clock.tv_nsec));
}

/* uptime, memfree, buffree: an empty request, a 4-byte reply. */
static void run_u32(const struct check *c, struct result *r, int port, const char *key) {
	uint8_t reply[REPLY_BUF];
	int n = transact(c->node, port, c->crc, NULL, 0, reply, &r->rtt_us);
	if (n < 0) {
		r->reason = no_reply_reason(r->rtt_us);
		return;
	}
	char hex[2 * REPLY_BUF + 1];
	common_hex(reply, (size_t)n, hex);
	if (n != 4) {
		r->reason = "length";
		add(r, " len=%d reply=%s", n, hex);
		return;
	}
	uint32_t be = (uint32_t)reply[0] << 24 | (uint32_t)reply[1] << 16 | (uint32_t)reply[2] << 8 | reply[3];
	uint32_t le = (uint32_t)reply[3] << 24 | (uint32_t)reply[2] << 16 | (uint32_t)reply[1] << 8 | reply[0];
	r->ok = 1;
	/* libcsp sends these in network byte order (big-endian); the twin's FC can be told to
	 * answer uptime as the ICD says (u32 LE milliseconds): both readings are printed for
	 * uptime, the raw bytes for all. */
	if (port == CSP_UPTIME)
		add(r, " %s=%" PRIu32 " le=%" PRIu32 " raw=%s", key, be, le, hex);
	else
		add(r, " %s=%" PRIu32 " raw=%s", key, be, hex);
}

/* ps: as csp_ps() does, a 1-byte request (0x55), then every reply packet until none comes
 * for a while (the reply has no end marker: csp_ps waits its whole timeout after the last
 * packet; we wait the timeout for the first and --ps-gap for each further one). */
static void run_ps(const struct check *c, struct result *r) {
	uint64_t t0 = common_now_us();
	csp_conn_t *conn = csp_connect(CSP_PRIO_NORM, (uint8_t)c->node, CSP_PS, timeout_ms,
				       c->crc ? CSP_O_CRC32 : CSP_O_NONE);
	if (conn == NULL) {
		r->rtt_us = common_now_us() - t0;
		r->reason = "error";
		return;
	}
	csp_packet_t *p = csp_buffer_get(1);
	if (p == NULL) {
		csp_close(conn);
		r->rtt_us = common_now_us() - t0;
		r->reason = "error";
		return;
	}
	p->data[0] = 0x55;
	p->length = 1;
	if (!csp_send(conn, p, 0)) {
		csp_buffer_free(p);
		csp_close(conn);
		r->rtt_us = common_now_us() - t0;
		r->reason = "error";
		return;
	}
	uint8_t text[2048];
	size_t len = 0;
	int packets = 0, max_packet = 0;
	while ((p = csp_read(conn, packets == 0 ? timeout_ms : ps_gap_ms)) != NULL) {
		if (packets == 0)
			r->rtt_us = common_now_us() - t0;
		packets++;
		if (p->length > max_packet)
			max_packet = p->length;
		size_t take = p->length;
		if (take > sizeof text - len)
			take = sizeof text - len;
		memcpy(text + len, p->data, take);
		len += take;
		csp_buffer_free(p);
	}
	csp_close(conn);
	if (packets == 0) {
		r->rtt_us = common_now_us() - t0;
		r->reason = "timeout";
		return;
	}
	char q[4 * sizeof text + 3];
	common_quote(text, len, 0, q, sizeof q);
	r->ok = 1;
	add(r, " packets=%d bytes=%zu max_packet=%d text=%s", packets, len, max_packet, q);
}

static void run_icd(const struct check *c, struct result *r) {
	uint8_t reply[REPLY_BUF];
	int n = transact(c->node, c->port, c->crc, c->req, c->req_len, reply, &r->rtt_us);
	if (n < 0) {
		r->reason = no_reply_reason(r->rtt_us);
		return;
	}
	char hex[2 * REPLY_BUF + 1];
	common_hex(reply, (size_t)n, hex);
	if (n != c->expected)
		r->reason = "length";
	else
		r->ok = 1;
	/* result is the reply's second byte (`command | result | data`, 1 = success). */
	add(r, " len=%d", n);
	if (n >= 2)
		add(r, " result=%u", reply[1]);
	add(r, " reply=%s", hex);
}

static void run_once(const struct check *c, struct result *r) {
	memset(r, 0, sizeof *r);
	switch (c->kind) {
	case K_PING: run_ping(c, r); break;
	case K_IDENT: run_ident(c, r); break;
	case K_CLOCK: run_clock(c, r); break;
	case K_UPTIME: run_u32(c, r, CSP_UPTIME, "uptime"); break;
	case K_PS: run_ps(c, r); break;
	case K_MEMFREE: run_u32(c, r, CSP_MEMFREE, "bytes"); break;
	case K_BUFFREE: run_u32(c, r, CSP_BUF_FREE, "buffers"); break;
	case K_ICD: run_icd(c, r); break;
	case K_RESERVED: run_reserved(c, r); break;
	}
}

static void report(int ok) {
	total++;
	if (ok)
		passed++;
	else
		failed++;
}

static int cmp_u64(const void *a, const void *b) {
	uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
	return x < y ? -1 : x > y;
}

static void run_check(const struct check *c) {
	char desc[1024];
	describe(c, desc, sizeof desc);
	const char *name = kind_names[c->kind];
	static struct result r;
	if (c->repeat == 0) {
		run_once(c, &r);
		printf("%s %s %s%s%s rtt_us=%" PRIu64 "%s\n", r.ok ? "ok" : "fail", name, desc,
		       r.reason ? " reason=" : "", r.reason ? r.reason : "", r.rtt_us, r.detail);
		fflush(stdout);
		report(r.ok);
		return;
	}
	/* repeat: round trips of the passing runs; the first failure's reason. */
	uint64_t *rtts = calloc((size_t)c->repeat, sizeof *rtts);
	if (rtts == NULL) {
		fprintf(stderr, "out of memory\n");
		exit(2);
	}
	int good = 0;
	const char *first_fail = NULL;
	for (int i = 0; i < c->repeat; i++) {
		run_once(c, &r);
		if (r.ok)
			rtts[good++] = r.rtt_us;
		else if (first_fail == NULL)
			first_fail = r.reason;
	}
	int ok = good == c->repeat;
	printf("%s repeat %s %s", ok ? "ok" : "fail", name, desc);
	if (!ok)
		printf(" reason=%s", first_fail ? first_fail : "error");
	printf(" n=%d passed=%d", c->repeat, good);
	if (good > 0) {
		qsort(rtts, (size_t)good, sizeof *rtts, cmp_u64);
		uint64_t sum = 0;
		for (int i = 0; i < good; i++)
			sum += rtts[i];
		/* median: the middle one, or the mean of the two middle ones */
		uint64_t median = good % 2 ? rtts[good / 2] : (rtts[good / 2 - 1] + rtts[good / 2]) / 2;
		printf(" min_us=%" PRIu64 " median_us=%" PRIu64 " mean_us=%" PRIu64 " max_us=%" PRIu64,
		       rtts[0], median, sum / (uint64_t)good, rtts[good - 1]);
	}
	printf("\n");
	fflush(stdout);
	free(rtts);
	report(ok);
}

/* The KISS device went away mid-run (the twin ended, socat exited). */
static void link_closed(void) {
	fflush(stdout);
	printf("fail link reason=device_closed\n");
	printf("summary checks=%u ok=%u fail=%u\n", total + 1, passed, failed + 1);
	fflush(stdout);
	fflush(stderr);
	_exit(1);
}

int main(int argc, char **argv) {
	struct common_opts o;
	common_opts_init(&o);
	char **tok = calloc((size_t)argc + 1, sizeof *tok);
	int ntok = 0;
	int all_icd_fc = 0, fc_tm_port = FC_TM_PORT_DEFAULT, gap_ms = 0, settle_ms = -1;
	if (tok == NULL)
		return 2;

	for (int i = 1; i < argc; i++) {
		const char *a = argv[i];
		int r = common_parse_opt(argc, argv, &i, &o);
		if (r < 0)
			return 2;
		if (r > 0)
			continue;
		const char *val = i + 1 < argc ? argv[i + 1] : NULL;
		int tmp;
		if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
			usage(stdout);
			return 0;
		} else if (!strcmp(a, "--timeout")) {
			if (parse_num(a, val, 1, 3600000, &tmp) < 0)
				return 2;
			timeout_ms = (uint32_t)tmp;
			i++;
		} else if (!strcmp(a, "--ps-gap")) {
			if (parse_num(a, val, 1, 3600000, &tmp) < 0)
				return 2;
			ps_gap_ms = (uint32_t)tmp;
			i++;
		} else if (!strcmp(a, "--gap")) {
			if (parse_num(a, val, 0, 3600000, &gap_ms) < 0)
				return 2;
			i++;
		} else if (!strcmp(a, "--settle")) {
			if (parse_num(a, val, 0, 3600000, &settle_ms) < 0)
				return 2;
			i++;
		} else if (!strcmp(a, "--all-icd-fc")) {
			all_icd_fc = 1;
		} else if (!strcmp(a, "--fc-tm-port")) {
			if (parse_num(a, val, 0, 63, &fc_tm_port) < 0)
				return 2;
			i++;
		} else if (a[0] == '-' && a[1] == '-') {
			fprintf(stderr, "unknown option: %s\n", a);
			usage(stderr);
			return 2;
		} else {
			tok[ntok++] = argv[i];
		}
	}
	if (common_check_opts(&o) < 0) {
		usage(stderr);
		return 2;
	}

	/* All checks are parsed before libcsp starts, so that a typo costs nothing. */
	size_t nfc = sizeof fc_telemetry / sizeof fc_telemetry[0];
	struct check *checks = calloc((size_t)ntok + nfc + 1, sizeof *checks);
	int nchecks = 0;
	if (checks == NULL)
		return 2;
	for (int p = 0; p < ntok;)
		if (parse_check(tok, ntok, &p, &checks[nchecks++], 1) < 0) {
			usage(stderr);
			return 2;
		}
	if (all_icd_fc)
		for (size_t k = 0; k < nfc; k++) {
			struct check *c = &checks[nchecks++];
			memset(c, 0, sizeof *c);
			c->kind = K_ICD;
			c->node = FC_ADDR;
			c->port = fc_tm_port;
			c->req[0] = fc_telemetry[k].cmd;
			c->req_len = 1;
			c->expected = fc_telemetry[k].reply_len;
		}
	if (nchecks == 0) {
		fprintf(stderr, "no checks given\n");
		usage(stderr);
		return 2;
	}

	common_set_link_closed_handler(link_closed);
	if (common_start(&o, "csp_client") < 0)
		return 2;
	if (settle_ms < 0)
		settle_ms = o.kind == IFACE_ZMQ ? 500 : 0;
	if (settle_ms > 0)
		usleep((useconds_t)settle_ms * 1000);

	for (int k = 0; k < nchecks; k++) {
		if (k > 0 && gap_ms > 0)
			usleep((useconds_t)gap_ms * 1000);
		run_check(&checks[k]);
	}
	printf("summary checks=%u ok=%u fail=%u\n", total, passed, failed);
	fflush(stdout);
	if (common_kiss_discarded() > 0)
		fprintf(stderr, "csp_client: %lu bytes outside KISS frames discarded\n",
			common_kiss_discarded());
	free(checks);
	free(tok);
	return failed == 0 ? 0 : 1;
}
