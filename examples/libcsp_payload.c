/* libcsp_payload.c: an M6P payload on the real libcsp 1.4, in one file, to copy from.
 *
 * What it is
 *   Payload 12 on the M6P's payload bus. It serves a polling session of the payload
 *   controller (PC, CSP 6) as docs/payload-guide.md "The rules your payload must follow"
 *   asks (ICD 3.1.8.2; a request is `command | args`, a reply `command | result | data`):
 *       SYNC  01 | message (0-128 bytes)   ->  01 01 | message (the same bytes)
 *       POLL  02 | frameSize (1 byte)      ->  02 01 | data (1 to frameSize bytes)
 *       anything else                      ->  command 00 (an empty request: 00 00)
 *   and answers the CSP services (ping, ps, memfree, buf_free, uptime, CMP) like any libcsp
 *   node, except reboot. Its data is examples/outside_payload.py's `frame_data` stream,
 *   byte for byte, so the two examples can be swapped and checked the same way.
 *
 * Build (from the repository root; --zmq needs libzmq3-dev; without it add -DNO_ZMQ and
 * drop -lzmq)
 *   third_party/libcsp-1.4/build.sh /tmp/libcsp
 *   cc -Wall -Wextra -O2 examples/libcsp_payload.c -I/tmp/libcsp/include \
 *      /tmp/libcsp/libcsp.a -lpthread -lrt -lm -lzmq -o /tmp/libcsp_payload
 *
 * Run against the twin (the scenario of examples/README.md with a `zmq-hub` or `kiss-pty`
 * link for address 12; start the twin first: with kiss-pty it is the twin that makes the pty)
 *   target/release/m6p-twin run /tmp/libcsp_payload.toml &
 *   /tmp/libcsp_payload --zmq 127.0.0.2 --sent /tmp/sent.bin       # twin = libcsp's ZMQ hub
 *   /tmp/libcsp_payload --kiss /tmp/m6p-tty --sent /tmp/sent.bin   # KISS on the twin's pty
 *
 * Options: --addr N (default 12), --sent FILE (every POLL data byte sent, in order),
 * --idle S (stop S seconds after the last POLL, default 3), --seconds S (overall limit,
 * default 0 = none). stdout: a line per SYNC, then `served syncs=N polls=N bytes=N`;
 * libcsp's own log and chatter go to stderr. Exit 0 if it served a SYNC and a POLL.
 *
 * The libcsp calls that matter, in the order main() makes them:
 *   csp_buffer_init, csp_set_hostname + csp_set_model, csp_init(addr)
 *   csp_zmqhub_init(addr, host)  or  usart_init + csp_kiss_init + usart_set_callback
 *   csp_route_set(CSP_DEFAULT_ROUTE, iface, CSP_NODE_MAC), csp_route_start_task
 *   csp_socket, csp_bind(10), csp_bind(CSP_ANY), csp_listen
 *   then for ever: csp_accept, csp_read, csp_send (port 10) / csp_service_handler, csp_close
 */
#define _DEFAULT_SOURCE /* usleep, dup2 with -std=c99/c11 too */
#include <ctype.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <csp/csp.h>
#include <csp/drivers/usart.h>
#include <csp/interfaces/csp_if_kiss.h>
#ifndef NO_ZMQ
#include <csp/interfaces/csp_if_zmqhub.h>
#endif

#define PAYLOAD_PORT 10 /* the PC sends SYNC and POLL to this port */
#define CMD_SYNC 0x01   /* commands (the first byte of a request and of its reply) */
#define CMD_POLL 0x02
#define RESULT_OK 0x01  /* results (the second byte of a reply) */
#define RESULT_FAIL 0x00

/* The session. `lock` because the end may come from libcsp's KISS receive thread. */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static unsigned syncs, polls, seq;
static unsigned long bytes_sent;
static FILE *sent;        /* --sent FILE, or NULL */
static double last_poll;  /* when the last POLL was served (monotonic s); 0: none yet */
static pthread_t main_thread;

static double now(void) {
	struct timespec t;
	clock_gettime(CLOCK_MONOTONIC, &t);
	return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

/* The summary, then the end of the process: _exit, because this may run on libcsp's receive
 * thread or inside exit(). The lock is never released: a second caller waits for the _exit. */
static void finish(const char *why) {
	pthread_mutex_lock(&lock);
	if (sent != NULL)
		fclose(sent);
	fprintf(stderr, "libcsp_payload: stopping: %s\n", why);
	printf("served syncs=%u polls=%u bytes=%lu\n", syncs, polls, bytes_sent);
	fflush(stdout);
	_exit(syncs > 0 && polls > 0 ? 0 : 1);
}

/* examples/outside_payload.py frame_data(seq, frameSize): seq as u16 little-endian, then a
 * byte counter from seq; the length cycles through frameSize, 2/3 and 1/3 of it (at least
 * 1), so the PC also gets replies shorter than it asked for. */
static size_t frame_data(unsigned s, unsigned frame_size, uint8_t *out) {
	long len = (long)frame_size - (long)(s % 3) * (long)(frame_size / 3);
	if (len < 1)
		len = 1;
	for (long k = 0; k < len; k++)
		out[k] = (uint8_t)(k == 0 ? s : k == 1 ? s >> 8 : s + (unsigned)(k - 2));
	return (size_t)len;
}

/* One request to port 10 in `req` (its CSP CRC, if any, already checked and stripped by
 * libcsp); the reply goes out in the same buffer. */
static void serve_request(csp_conn_t *conn, csp_packet_t *req) {
	const uint8_t *d = req->data;
	size_t n = req->length;
	uint8_t r[2 + 256];                 /* the reply: command, result, data */
	size_t rn = 2;
	r[0] = n > 0 ? d[0] : 0x00;
	r[1] = RESULT_FAIL;
	pthread_mutex_lock(&lock);
	if (n >= 1 && d[0] == CMD_SYNC && n - 1 <= 128) {
		r[1] = RESULT_OK;           /* echo the message, exactly */
		memcpy(r + 2, d + 1, n - 1);
		rn += n - 1;
		syncs++;
		printf("sync len=%zu message=\"", n - 1);
		for (size_t i = 1; i < n; i++) {   /* printable as is, the rest as \xHH */
			if (isprint(d[i]) && d[i] != '"' && d[i] != '\\')
				putchar(d[i]);
			else
				printf("\\x%02x", d[i]);
		}
		printf("\"\n");
		fflush(stdout);
	} else if (n == 2 && d[0] == CMD_POLL && d[1] > 0) {
		r[1] = RESULT_OK;           /* the next frame, at most frameSize bytes */
		rn += frame_data(seq++, d[1], r + 2);
		last_poll = now();
	}
	/* Reuse the request's buffer (it holds 300 bytes, see csp_buffer_init). csp_send on the
	 * connection answers the request's source address and port, from port 10, with its
	 * priority and flags: a request with CSP's CRC flag gets a reply with a CRC. (With
	 * csp_sendto, connection-less, you would have to mirror the CRC flag yourself.) */
	memcpy(req->data, r, rn);
	req->length = (uint16_t)rn;
	if (!csp_send(conn, req, 0)) {
		fprintf(stderr, "libcsp_payload: csp_send failed\n");
		csp_buffer_free(req);       /* on failure the buffer is still ours */
	} else if (r[0] == CMD_POLL && r[1] == RESULT_OK) {
		polls++;
		bytes_sent += rn - 2;
		if (sent != NULL && (fwrite(r + 2, 1, rn - 2, sent) != rn - 2 || fflush(sent) != 0))
			perror("libcsp_payload: --sent");
	}
	pthread_mutex_unlock(&lock);
}

/* ---- KISS on a serial device or the twin's pty, wired as libcsp 1.4's examples/kiss.c ---- */

static csp_iface_t kiss_if;
static csp_kiss_handle_t kiss_handle;

/* libcsp 1.4's usart receive thread keeps read()'s result in an *unsigned* int: when the
 * twin closes its end of the pty, read() fails with EIO and we are handed len = -1, with
 * which csp_kiss_rx would run off its buffer (SIGSEGV). A read() of 0 makes the driver call
 * exit(1) instead (caught by exit_hook). Either way the link is gone: stop cleanly. */
static void kiss_rx(uint8_t *buf, int len, void *woken) {
	if (len <= 0)
		finish("the KISS device closed");
	csp_kiss_rx(&kiss_if, buf, len, woken);
}

static void exit_hook(void) {
	if (!pthread_equal(pthread_self(), main_thread))
		finish("the KISS device closed");
}

/* Bytes between KISS frames: libcsp's example prints them on stdout (usart_insert). */
static void kiss_discard(char c, void *woken) { (void)c; (void)woken; }

/* libcsp's log (printf to stdout by default) to stderr. */
static void log_hook(csp_debug_level_t level, const char *fmt, va_list args) {
	fprintf(stderr, "csp[%d]: ", (int)level);
	vfprintf(stderr, fmt, args);
	fputc('\n', stderr);
}

int main(int argc, char **argv) {
	const char *zmq_host = NULL, *kiss_dev = NULL, *sent_path = NULL;
	int addr = 12;
	double idle = 3, seconds = 0;
	for (int i = 1; i < argc; i++) {
		const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
		if (v == NULL)
			goto usage;
		if (!strcmp(o, "--zmq")) zmq_host = v;
		else if (!strcmp(o, "--kiss")) kiss_dev = v;
		else if (!strcmp(o, "--addr")) addr = atoi(v);
		else if (!strcmp(o, "--sent")) sent_path = v;
		else if (!strcmp(o, "--idle")) idle = atof(v);
		else if (!strcmp(o, "--seconds")) seconds = atof(v);
		else goto usage;
		i++;
	}
	if (!zmq_host == !kiss_dev || addr < 0 || addr > 30 || idle <= 0 || seconds < 0)
		goto usage;
	if (sent_path != NULL && (sent = fopen(sent_path, "wb")) == NULL) {
		perror(sent_path);
		return 2;
	}
	setvbuf(stdout, NULL, _IOLBF, 0);
	main_thread = pthread_self();

	/* 1. libcsp itself. Buffers of 300 data bytes: the KISS and ZMQ receivers take one of
	 * 256 (the MTU) per packet, and a reply with CRC grows by 4 + 4 (CSP + KISS CRC32). CMP
	 * ident copies the hostname and model: they must be set (NULL crashes it). */
	csp_debug_hook_set(log_hook);
	csp_buffer_init(100, 300);
	csp_set_hostname("libcsp_payload");
	csp_set_model("m6p-twin example");
	csp_init((uint8_t)addr);

	/* 2. The interface, and every destination but ourselves routed to it. CSP_NODE_MAC: the
	 * next hop is the destination itself (on the hub: the ZMQ topic; KISS ignores it, the
	 * twin behind the link routes onwards). Both inits printf chatter: off our stdout. */
	csp_iface_t *iface = &kiss_if;
	fflush(stdout);
	int saved_stdout = dup(1);
	dup2(2, 1);
	if (zmq_host != NULL) {
#ifndef NO_ZMQ
		/* PUB to tcp://HOST:6000, SUB to tcp://HOST:7000, subscribed to our address. */
		if (csp_zmqhub_init((char)addr, (char *)zmq_host) != CSP_ERR_NONE)
			return 2;
		iface = &csp_if_zmqhub;
#else
		fprintf(stderr, "built with -DNO_ZMQ\n");
		return 2;
#endif
	} else {
		/* usart_init fails silently if the device is not there: wait up to 10 s for it. */
		for (int i = 0; access(kiss_dev, R_OK | W_OK) != 0; i++) {
			if (i == 100) {
				perror(kiss_dev);
				return 2;
			}
			usleep(100000);
		}
		struct usart_conf conf = {.device = kiss_dev, .baudrate = 500000, .databits = 8, .stopbits = 1};
		atexit(exit_hook);
		usart_init(&conf);          /* opens the device, starts the receive thread */
		csp_kiss_init(&kiss_if, &kiss_handle, usart_putc, kiss_discard, "KISS");
		usart_set_callback(kiss_rx);
	}
	fflush(stdout);
	dup2(saved_stdout, 1);
	close(saved_stdout);
	csp_route_set(CSP_DEFAULT_ROUTE, iface, CSP_NODE_MAC);
	csp_route_start_task(0, 0);     /* the router: packets from the interface to our sockets */

	/* 3. One socket for everything: port 10 and, with CSP_ANY, every other port (the
	 * services 0-6). In 1.4 the router answers no service itself: we hand those connections
	 * to csp_service_handler, all but reboot (4), which on POSIX would call reboot(2). */
	csp_socket_t *sock = csp_socket(CSP_SO_NONE);
	if (sock == NULL || csp_bind(sock, PAYLOAD_PORT) != CSP_ERR_NONE ||
	    csp_bind(sock, CSP_ANY) != CSP_ERR_NONE || csp_listen(sock, 10) != CSP_ERR_NONE) {
		fprintf(stderr, "libcsp_payload: cannot listen on port %d\n", PAYLOAD_PORT);
		return 2;
	}
	fprintf(stderr, "libcsp_payload: CSP %d on %s, serving port %d\n", addr,
		zmq_host != NULL ? "the ZMQ hub" : "KISS", PAYLOAD_PORT);
	double start = now();
	for (;;) {
		if (seconds > 0 && now() - start >= seconds)
			finish("--seconds elapsed");
		if (last_poll > 0 && now() - last_poll >= idle)
			finish("no POLL for --idle seconds: the session is over");
		csp_conn_t *conn = csp_accept(sock, 100);   /* ms; then look at the clock again */
		if (conn == NULL)
			continue;
		/* The PC sends each request from a new port, hence on a new connection: read what
		 * it holds, without waiting for more once served (the next request is queued). */
		csp_packet_t *p;
		for (int first = 1; (p = csp_read(conn, first ? 100 : 0)) != NULL; first = 0) {
			if (csp_conn_dport(conn) == PAYLOAD_PORT)
				serve_request(conn, p);
			else if (csp_conn_dport(conn) == CSP_REBOOT)
				csp_buffer_free(p);
			else
				csp_service_handler(conn, p); /* sends or frees p */
		}
		csp_close(conn);
	}

usage:
	fprintf(stderr, "usage: %s (--zmq HOST | --kiss PATH) [--addr 12] [--sent FILE] "
		"[--idle 3] [--seconds 0]\n", argv[0]);
	return 2;
}
