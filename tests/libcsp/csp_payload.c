/* csp_payload: an M6P payload built on the real libcsp 1.4 that serves the payload
 * controller's polling session (PC, CSP 6, the master), the C twin of
 * examples/outside_payload.py.
 *
 *   csp_payload (--kiss PATH | --zmq HOST | --can IFNAME) [--addr 12] [--api conn|connless]
 *               [--port 10] [--sent FILE] [--idle S] [--seconds S] [--verbose]
 *
 * The protocol (docs/payload-guide.md "The rules your payload must follow", ICD 3.1.8.2;
 * a request is `command | data`, a reply `command | result | data`, result 1 = success):
 *   SYNC  request  01 | message (0-128 bytes)   reply  01 01 | message (the same bytes)
 *   POLL  request  02 | frameSize (1 byte)      reply  02 01 | data (1 to frameSize bytes)
 * anything else: `command 00` (an empty request: `00 00`), as the Python example does.
 * Replies go to the request's source address and port, from the port it came to, with its
 * priority and flags (so a request with CSP's CRC flag gets a reply with it).
 *
 * Two ways of using libcsp, chosen by --api:
 *   conn      (default) csp_socket(0) bound to PORT and to CSP_ANY, csp_listen,
 *             csp_accept; each accepted connection is read with csp_read and answered with
 *             csp_send on the connection, then csp_close. Connections to other ports (CSP
 *             services 0-6) go to csp_service_handler, as libcsp applications do.
 *   connless  csp_socket(CSP_SO_CONN_LESS) bound to PORT; csp_recvfrom, and csp_sendto to
 *             the request's src/sport from its dport with its priority and CRC flag (what
 *             csp_sendto_reply does). The CSP services are answered by a second thread
 *             with a connection socket on CSP_ANY and csp_service_handler.
 * In libcsp 1.4 the router does not answer services by itself: a node answers ping (1),
 * ps (2), memfree (3), buf_free (5), uptime (6) and CMP (0: ident, clock ...) only if the
 * application passes such connections to csp_service_handler. Both modes do, except for
 * reboot (4), which this program drops (libcsp's POSIX port would reboot the host).
 *
 * The data is examples/outside_payload.py's deterministic stream `frame_data`, byte for
 * byte: POLL number seq (from 0) for frameSize F gets
 *     length = max(1, F - (seq % 3) * (F / 3))
 *     bytes  = the first `length` bytes of: seq as u16 little-endian, then (seq + i) & 0xFF
 *              for i = 0, 1, 2, ...
 * Every data byte sent in a POLL reply is appended to --sent FILE, in order (flushed at
 * once), so that it can be compared with what the twin downlinked (`cmp`).
 *
 * It stops after --idle seconds (default 3) without a POLL once one came, after --seconds
 * (no limit by default), on SIGINT/SIGTERM, or when the KISS device closes (the twin's
 * link, hence socat's pty, went away: a normal end of a run). Then it prints
 *     served syncs=N polls=N bytes=N refused=N reason=WHY
 * (WHY: idle, seconds, signal, device_closed), and exits 0 if it served at least one SYNC
 * and one POLL, 1 otherwise, 2 on a usage or setup error. Each SYNC it acknowledges is
 * also printed (`sync len=N message="..."`), and each POLL with --verbose
 * (`poll seq=N frame_size=N len=N`).
 */
#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <csp/csp.h>

#include "common.h"

#define CMD_SYNC 0x01
#define CMD_POLL 0x02
#define RESULT_OK 0x01
#define RESULT_FAIL 0x00
#define SYNC_MAX_BYTES 128 /* ICD 3.1.8.2 table 5: the sync message is 0-128 bytes */
#define ACCEPT_POLL_MS 100 /* how often the loops look at the clock and the signal flag */

static const char *sent_path;
static FILE *sent_file;
static int verbose;

/* The session's state. Touched by the main thread (conn: the accept loop; connless: the
 * recvfrom loop) under `lock`; read by the shutdown path under it too. */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static unsigned seq, syncs, polls, refused;
static unsigned long bytes_sent;
static uint64_t last_poll_us; /* 0: no POLL yet */
static volatile sig_atomic_t stop_signal;

static void on_signal(int sig) {
	(void)sig;
	stop_signal = 1;
}

/* examples/outside_payload.py frame_data(seq, frame_size), byte for byte. */
static size_t frame_data(unsigned s, unsigned frame_size, uint8_t *out) {
	long length = (long)frame_size - (long)(s % 3) * (long)(frame_size / 3);
	if (length < 1)
		length = 1;
	for (long k = 0; k < length; k++) {
		if (k == 0)
			out[k] = (uint8_t)(s & 0xff);         /* seq & 0xFFFF, little-endian */
		else if (k == 1)
			out[k] = (uint8_t)((s >> 8) & 0xff);
		else
			out[k] = (uint8_t)((s + (unsigned)(k - 2)) & 0xff); /* the byte counter */
	}
	return (size_t)length;
}

/* The reply to one request on the payload port; returns its length. `reply` holds at
 * least 2 + 255 bytes. A POLL's frame is only counted (and logged to --sent) by the caller
 * once libcsp has taken the reply: *poll_data and *poll_len say which bytes those are. */
static size_t handle_request(const uint8_t *data, size_t len, uint8_t *reply,
			     const uint8_t **poll_data, size_t *poll_len) {
	*poll_data = NULL;
	*poll_len = 0;
	if (len == 0) {
		refused++;
		reply[0] = 0x00;
		reply[1] = RESULT_FAIL;
		return 2;
	}
	uint8_t cmd = data[0];
	const uint8_t *args = data + 1;
	size_t nargs = len - 1;
	reply[0] = cmd;
	if (cmd == CMD_SYNC) {
		if (nargs > SYNC_MAX_BYTES) {
			refused++;
			reply[1] = RESULT_FAIL;
			return 2;
		}
		syncs++;
		reply[1] = RESULT_OK;
		memcpy(reply + 2, args, nargs);
		char q[4 * SYNC_MAX_BYTES + 3];
		common_quote(args, nargs, 0, q, sizeof q);
		printf("sync len=%zu message=%s\n", nargs, q);
		fflush(stdout);
		return 2 + nargs;
	}
	if (cmd == CMD_POLL) {
		if (nargs != 1 || args[0] == 0) {
			refused++;
			reply[1] = RESULT_FAIL;
			return 2;
		}
		size_t n = frame_data(seq, args[0], reply + 2);
		if (verbose) {
			printf("poll seq=%u frame_size=%u len=%zu\n", seq, args[0], n);
			fflush(stdout);
		}
		seq++; /* as the Python example: the frame number advances whatever happens next */
		last_poll_us = common_now_us();
		reply[1] = RESULT_OK;
		*poll_data = reply + 2;
		*poll_len = n;
		return 2 + n;
	}
	refused++;
	reply[1] = RESULT_FAIL;
	return 2;
}

/* A POLL reply went out: count it and log its data bytes. */
static void poll_sent(const uint8_t *data, size_t n) {
	polls++;
	bytes_sent += n;
	if (sent_file != NULL) {
		if (fwrite(data, 1, n, sent_file) != n || fflush(sent_file) != 0)
			fprintf(stderr, "csp_payload: writing %s: %s\n", sent_path, strerror(errno));
	}
}

/* Builds the reply packet (a fresh libcsp buffer) for the request `req`, or NULL. */
static csp_packet_t *make_reply(const csp_packet_t *req, const uint8_t **poll_data, size_t *poll_len) {
	uint8_t reply[2 + 256];
	size_t n = handle_request(req->data, req->length, reply, poll_data, poll_len);
	csp_packet_t *p = csp_buffer_get(n);
	if (p == NULL) {
		fprintf(stderr, "csp_payload: no libcsp buffer for a %zu-byte reply\n", n);
		return NULL;
	}
	memcpy(p->data, reply, n);
	p->length = (uint16_t)n;
	/* the POLL data now lives in the packet */
	if (*poll_data != NULL)
		*poll_data = p->data + 2;
	return p;
}

/* ---------------------------------------------------------------------------------------
 * The end. */

static int finished;

/* Prints the summary, closes --sent and ends the process: _exit, because it may run inside
 * exit() (common.c's link-closed path) or on libcsp's receive thread. */
static void finish(const char *reason) {
	pthread_mutex_lock(&lock);
	if (finished++) { /* someone else is already finishing */
		pthread_mutex_unlock(&lock);
		for (;;)
			pause();
	}
	if (sent_file != NULL)
		fclose(sent_file);
	sent_file = NULL;
	int served = syncs > 0 && polls > 0;
	printf("served syncs=%u polls=%u bytes=%lu refused=%u reason=%s\n", syncs, polls, bytes_sent,
	       refused, reason);
	fflush(stdout);
	if (common_kiss_discarded() > 0)
		fprintf(stderr, "csp_payload: %lu bytes outside KISS frames discarded\n",
			common_kiss_discarded());
	fflush(stderr);
	_exit(served ? 0 : 1);
}

static void link_closed(void) {
	finish("device_closed");
}

/* Whether the main loop should stop now; sets *why. */
static int should_stop(uint64_t start_us, double seconds, double idle, const char **why) {
	uint64_t now = common_now_us();
	if (stop_signal) {
		*why = "signal";
		return 1;
	}
	if (seconds > 0 && now - start_us >= (uint64_t)(seconds * 1e6)) {
		*why = "seconds";
		return 1;
	}
	pthread_mutex_lock(&lock);
	uint64_t last = last_poll_us;
	pthread_mutex_unlock(&lock);
	if (last != 0 && now - last >= (uint64_t)(idle * 1e6)) {
		*why = "idle";
		return 1;
	}
	return 0;
}

/* A packet on a CSP service port: to libcsp's csp_service_handler, except reboot (port 4).
 * libcsp 1.4's POSIX csp_sys_reboot really calls reboot(2) when the request carries the
 * magic word 0x80078007: a test peer must not be able to restart the machine it runs on
 * (a twin scenario can send `request = "reboot"`). Reboot requests are dropped and logged:
 * a real node would not answer either. */
static void serve_service(csp_conn_t *conn, csp_packet_t *p) {
	if (csp_conn_dport(conn) == CSP_REBOOT) {
		fprintf(stderr, "csp_payload: reboot request from %d ignored\n", csp_conn_src(conn));
		csp_buffer_free(p);
		return;
	}
	csp_service_handler(conn, p); /* frees or sends p */
}

/* ---------------------------------------------------------------------------------------
 * --api conn */

static const char *serve_conn(int port, uint64_t start_us, double seconds, double idle) {
	const char *why = NULL;
	csp_socket_t *sock = csp_socket(CSP_SO_NONE);
	if (sock == NULL || csp_bind(sock, (uint8_t)port) != CSP_ERR_NONE ||
	    csp_bind(sock, CSP_ANY) != CSP_ERR_NONE || csp_listen(sock, 10) != CSP_ERR_NONE) {
		fprintf(stderr, "csp_payload: cannot bind/listen on port %d\n", port);
		return NULL;
	}
	while (!should_stop(start_us, seconds, idle, &why)) {
		csp_conn_t *conn = csp_accept(sock, ACCEPT_POLL_MS);
		if (conn == NULL)
			continue;
		/* A connection holds the packets of one (src, sport) pair; the PC sends each
		 * request from a new ephemeral port, so there is usually one. Read what is there
		 * (libcsp's examples loop on csp_read the same way) but do not wait for more once
		 * the first is served: while we wait, the next request (a new connection) would
		 * sit in the accept queue, and its round trip would grow by the wait. */
		csp_packet_t *req;
		int first = 1;
		while ((req = csp_read(conn, first ? ACCEPT_POLL_MS : 0)) != NULL) {
			first = 0;
			if (csp_conn_dport(conn) != port) {
				serve_service(conn, req);
				continue;
			}
			pthread_mutex_lock(&lock);
			const uint8_t *pd;
			size_t pn;
			csp_packet_t *reply = make_reply(req, &pd, &pn);
			csp_buffer_free(req);
			/* csp_send replies on the connection: to the request's src and sport, from its
			 * dport, with its priority and flags (csp_route.c copies them into idout). */
			if (reply != NULL) {
				if (pd != NULL) {
					/* log before the packet (and pd with it) belongs to libcsp */
					uint8_t copy[256];
					memcpy(copy, pd, pn);
					if (csp_send(conn, reply, 0))
						poll_sent(copy, pn);
					else {
						fprintf(stderr, "csp_payload: csp_send failed (POLL reply of %zu bytes)\n", pn + 2);
						csp_buffer_free(reply);
					}
				} else if (!csp_send(conn, reply, 0)) {
					fprintf(stderr, "csp_payload: csp_send failed\n");
					csp_buffer_free(reply);
				}
			}
			pthread_mutex_unlock(&lock);
		}
		csp_close(conn);
	}
	return why;
}

/* ---------------------------------------------------------------------------------------
 * --api connless */

static void *service_thread(void *arg) {
	csp_socket_t *sock = arg;
	for (;;) {
		csp_conn_t *conn = csp_accept(sock, 1000);
		if (conn == NULL)
			continue;
		csp_packet_t *p;
		int first = 1;
		while ((p = csp_read(conn, first ? ACCEPT_POLL_MS : 0)) != NULL) {
			first = 0;
			serve_service(conn, p);
		}
		csp_close(conn);
	}
	return NULL;
}

static const char *serve_connless(int port, uint64_t start_us, double seconds, double idle) {
	const char *why = NULL;
	csp_socket_t *sock = csp_socket(CSP_SO_CONN_LESS);
	if (sock == NULL || csp_bind(sock, (uint8_t)port) != CSP_ERR_NONE) {
		fprintf(stderr, "csp_payload: cannot bind a connection-less socket on port %d\n", port);
		return NULL;
	}
	/* The services: every other port. libcsp's router looks for a socket on the packet's
	 * port first and falls back to CSP_ANY, so PORT stays with the connection-less one. */
	csp_socket_t *svc = csp_socket(CSP_SO_NONE);
	pthread_t th;
	if (svc == NULL || csp_bind(svc, CSP_ANY) != CSP_ERR_NONE || csp_listen(svc, 10) != CSP_ERR_NONE ||
	    pthread_create(&th, NULL, service_thread, svc) != 0) {
		fprintf(stderr, "csp_payload: cannot start the service socket\n");
		return NULL;
	}
	pthread_detach(th);
	while (!should_stop(start_us, seconds, idle, &why)) {
		csp_packet_t *req = csp_recvfrom(sock, ACCEPT_POLL_MS);
		if (req == NULL)
			continue;
		/* libcsp has checked and stripped a CSP CRC already (the flag stays in id). */
		pthread_mutex_lock(&lock);
		const uint8_t *pd;
		size_t pn;
		csp_packet_t *reply = make_reply(req, &pd, &pn);
		if (reply != NULL) {
			uint8_t copy[256];
			if (pd != NULL)
				memcpy(copy, pd, pn);
			/* csp_sendto clears the flags and sets CRC32 only from opts: mirror the
			 * request's CRC flag that way (HMAC, XTEA, RDP are not built in). */
			uint32_t opts = (req->id.flags & CSP_FCRC32) ? CSP_O_CRC32 : CSP_O_NONE;
			int e = csp_sendto(req->id.pri, req->id.src, req->id.sport, req->id.dport, opts, reply, 0);
			if (e == CSP_ERR_NONE) {
				if (pd != NULL)
					poll_sent(copy, pn);
			} else {
				fprintf(stderr, "csp_payload: csp_sendto failed (%d)\n", e);
				csp_buffer_free(reply); /* csp_sendto does not free on failure */
			}
		}
		csp_buffer_free(req);
		pthread_mutex_unlock(&lock);
	}
	return why;
}

/* ---------------------------------------------------------------------------------------
 * main */

static void usage(FILE *f) {
	fprintf(f,
		"usage: csp_payload (--kiss PATH | --zmq HOST | --can IFNAME) [options]\n"
		"%s"
		"payload:\n"
		"  (--addr defaults to 12)\n"
		"  --api conn|connless   libcsp connection sockets (default) or connection-less\n"
		"  --port P              the SYNC/POLL port (default 10)\n"
		"  --sent FILE           append every POLL data byte sent to FILE (truncated first)\n"
		"  --idle S              stop after S seconds without a POLL once one came (default 3)\n"
		"  --seconds S           stop after S seconds whatever happens (default: no limit)\n"
		"  --verbose             print a line per POLL\n",
		common_usage);
}

static int parse_seconds(const char *opt, const char *s, double *out) {
	char *end = NULL;
	if (s == NULL) {
		fprintf(stderr, "%s needs a value\n", opt);
		return -1;
	}
	errno = 0;
	double v = strtod(s, &end);
	if (errno != 0 || end == s || *end != '\0' || v <= 0 || v > 1e7) {
		fprintf(stderr, "%s: not a positive number of seconds: %s\n", opt, s);
		return -1;
	}
	*out = v;
	return 0;
}

int main(int argc, char **argv) {
	struct common_opts o;
	common_opts_init(&o);
	o.addr = 12;
	int connless = 0;
	long port = 10;
	double idle = 3.0, seconds = 0;

	for (int i = 1; i < argc; i++) {
		const char *a = argv[i];
		int r = common_parse_opt(argc, argv, &i, &o);
		if (r < 0)
			return 2;
		if (r > 0)
			continue;
		const char *val = i + 1 < argc ? argv[i + 1] : NULL;
		if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
			usage(stdout);
			return 0;
		} else if (!strcmp(a, "--api")) {
			if (val != NULL && !strcmp(val, "conn"))
				connless = 0;
			else if (val != NULL && !strcmp(val, "connless"))
				connless = 1;
			else {
				fprintf(stderr, "--api: conn or connless\n");
				return 2;
			}
			i++;
		} else if (!strcmp(a, "--port")) {
			/* 7..CSP_MAX_BIND_PORT: above the service ports, within what csp_bind takes */
			if (common_parse_long(val, 7, CSP_MAX_BIND_PORT, &port) < 0) {
				fprintf(stderr, "--port: 7-%d\n", CSP_MAX_BIND_PORT);
				return 2;
			}
			i++;
		} else if (!strcmp(a, "--sent")) {
			if (val == NULL) {
				fprintf(stderr, "--sent needs a file\n");
				return 2;
			}
			sent_path = val;
			i++;
		} else if (!strcmp(a, "--idle")) {
			if (parse_seconds(a, val, &idle) < 0)
				return 2;
			i++;
		} else if (!strcmp(a, "--seconds")) {
			if (parse_seconds(a, val, &seconds) < 0)
				return 2;
			i++;
		} else if (!strcmp(a, "--verbose")) {
			verbose = 1;
		} else {
			fprintf(stderr, "unknown argument: %s\n", a);
			usage(stderr);
			return 2;
		}
	}
	if (common_check_opts(&o) < 0) {
		usage(stderr);
		return 2;
	}
	if (sent_path != NULL && (sent_file = fopen(sent_path, "wb")) == NULL) {
		fprintf(stderr, "--sent: cannot create %s: %s\n", sent_path, strerror(errno));
		return 2;
	}

	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	common_set_link_closed_handler(link_closed);
	if (common_start(&o, "csp_payload") < 0)
		return 2;
	printf("listening addr=%d port=%ld api=%s iface=%s\n", o.addr, port, connless ? "connless" : "conn",
	       common_iface_name());
	fflush(stdout);

	uint64_t start = common_now_us();
	const char *why = connless ? serve_connless((int)port, start, seconds, idle)
				   : serve_conn((int)port, start, seconds, idle);
	if (why == NULL) {
		fflush(stdout);
		_exit(2);
	}
	finish(why);
	return 0; /* not reached */
}
