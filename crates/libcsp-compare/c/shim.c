/* Timing shim over the vendored, unmodified libcsp 1.4 (third_party/libcsp-1.4/, LGPL-2.1,
 * linked only into this crate's tests and benchmark), for crates/libcsp-compare.
 *
 * Every m6p_* timing function runs one operation `iters` times in a loop and returns the
 * elapsed time in nanoseconds (clock_gettime(CLOCK_MONOTONIC) around the loop, so the cost
 * of the call from Rust is not counted), or a negative value when libcsp failed. Each also
 * hands back what the last iteration produced (KISS frame, CAN frames, CRC value) so that
 * the Rust side can check libcsp and the project produce the same bytes.
 *
 * What one iteration is, exactly:
 * - KISS: csp_buffer_get(len), header and `len` data bytes copied in, then libcsp's own KISS
 *   transmit (the KISS interface's nexthop, static csp_kiss_tx in csp_if_kiss.c): CRC32C
 *   appended, header to network order, the frame written byte by byte through the putc
 *   callback (ours stores into a memory buffer), the buffer freed. csp_kiss_tx consumes and
 *   modifies the packet, so getting and filling a buffer is part of every iteration.
 * - CFP: csp_buffer_get + copy as above, then csp_can_tx (the CAN interface's nexthop) with
 *   timeout 0 into the dummy driver below: can_send copies the frame into memory; the
 *   "transmit complete" callback libcsp gave can_init (csp_tx_callback) is then called for
 *   each sent frame, as a real driver's TX interrupt or mailbox thread does, and sends the
 *   next frame; after the last one libcsp frees its CFP slot and the packet.
 * - CRC: one csp_crc32_memory call (libcsp 1.4's table is a const array: no init needed).
 * - ping: one csp_ping(own address, timeout, len, CSP_O_NONE): csp_connect, buffer, send
 *   through the loopback interface into the router task's queue, the router hands the new
 *   connection to the server thread below (csp_accept, csp_read, csp_service_handler echoes
 *   it back through the router), csp_read of the reply, the echo checked, csp_close.
 * - buffer cycle (for reference, not a comparison): csp_buffer_get + copy + csp_buffer_free,
 *   the part of the KISS and CFP iterations that is libcsp's buffer handling.
 *
 * Setup (m6p_shim_init, once per process, thread safe): csp_buffer_init, csp_init, a KISS
 * interface with a memory putc, the CAN interface on the dummy driver, the router task and
 * the service server thread. Every timing function holds one process-wide lock: the KISS
 * and CAN output buffers are global because libcsp's callbacks carry no context.
 */
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include <csp/csp.h>
#include <csp/csp_crc32.h>
#include <csp/interfaces/csp_if_can.h>
#include <csp/interfaces/csp_if_kiss.h>
/* libcsp's internal CAN driver interface (src/drivers/can/can.h): can_init, can_send. */
#include "drivers/can/can.h"

/* Our CSP address. */
#define SHIM_ADDR 10
/* Buffers: data size 300 (a 256-byte packet grows by the KISS CRC in place). */
#define BUF_COUNT 20
#define BUF_DATA_SIZE 300
/* The largest KISS frame: every byte of header + 256 data + CRC escaped, plus 3. */
#define KISS_OUT_MAX (2 * (4 + 256 + 4) + 3)
/* The most frames a 256-byte packet takes. */
#define CAN_OUT_MAX 40

/* Error codes (negative returns), beyond libcsp's own. */
#define SHIM_ERR_INIT -1001
#define SHIM_ERR_BUFFER -1002
#define SHIM_ERR_TX -1003
#define SHIM_ERR_OVERFLOW -1004
#define SHIM_ERR_ARG -1005
#define SHIM_ERR_PING -1006

/* One CAN frame as the dummy driver stores it; mirrored by the Rust side. */
struct m6p_frame {
	uint32_t id;
	uint8_t dlc;
	uint8_t data[8];
};

static pthread_mutex_t op_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_once_t init_once = PTHREAD_ONCE_INIT;
static int init_result = SHIM_ERR_INIT;

static int64_t now_ns(void) {
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* ---------------------------------------------------------------------------------------
 * libcsp's log, to stderr (csp_debug prints to stdout otherwise). */

static void log_hook(csp_debug_level_t level, const char *format, va_list args) {
	char msg[512];
	vsnprintf(msg, sizeof msg, format, args);
	fprintf(stderr, "libcsp (level %d): %s\n", (int)level, msg);
}

/* ---------------------------------------------------------------------------------------
 * KISS: libcsp writes the frame byte by byte through putc. */

static csp_iface_t kiss_iface;
static csp_kiss_handle_t kiss_handle;
static uint8_t kiss_out[KISS_OUT_MAX];
static size_t kiss_len;
static int kiss_overflow;

static void kiss_putc(char c) {
	if (kiss_len < sizeof kiss_out) {
		kiss_out[kiss_len++] = (uint8_t)c;
	} else {
		kiss_overflow = 1;
	}
}

/* ---------------------------------------------------------------------------------------
 * The dummy CAN driver (replaces libcsp's SocketCAN driver, whose object build.rs removes
 * from the archive): can_send copies the frame; the pending "transmit complete" is
 * delivered by run_can_tx. */

static can_tx_callback_t can_txcb;
static struct m6p_frame can_out[CAN_OUT_MAX];
static size_t can_count;
static int can_pending;
static can_id_t can_pending_id;

int can_init(uint32_t id, uint32_t mask, can_tx_callback_t atxcb, can_rx_callback_t arxcb,
	     struct csp_can_config *conf) {
	(void)id;
	(void)mask;
	(void)arxcb;
	(void)conf;
	can_txcb = atxcb;
	return 0;
}

int can_send(can_id_t id, uint8_t *data, uint8_t dlc, CSP_BASE_TYPE *task_woken) {
	(void)task_woken;
	if (dlc > 8 || can_count >= CAN_OUT_MAX || can_pending)
		return -1;
	struct m6p_frame *f = &can_out[can_count++];
	f->id = id;
	f->dlc = dlc;
	memset(f->data, 0, sizeof f->data);
	memcpy(f->data, data, dlc);
	can_pending = 1;
	can_pending_id = id;
	return 0;
}

/* ---------------------------------------------------------------------------------------
 * The service server: answers ping (and the other service ports) on every port, as a libcsp
 * application does; libcsp's router does not answer services itself. */

static csp_socket_t *server_socket;

static void *server_task(void *arg) {
	(void)arg;
	for (;;) {
		csp_conn_t *conn = csp_accept(server_socket, CSP_MAX_DELAY);
		if (conn == NULL)
			continue;
		/* The router queues the packet on the connection before the connection on the
		 * socket: it is there already. */
		csp_packet_t *packet;
		while ((packet = csp_read(conn, 0)) != NULL)
			csp_service_handler(conn, packet);
		csp_close(conn);
	}
	return NULL;
}

/* ---------------------------------------------------------------------------------------
 * Setup. */

static void init_once_fn(void) {
	static char hostname[] = "m6p-libcsp-compare";
	static char model[] = "m6p-twin libcsp-1.4 benchmark";
	static char kiss_name[] = "KISS";
	static char can_name[] = "dummy";
	static struct csp_can_config can_conf;
	pthread_t server;

	csp_debug_hook_set(log_hook);
	if (csp_buffer_init(BUF_COUNT, BUF_DATA_SIZE) != CSP_ERR_NONE)
		return;
	csp_set_hostname(hostname);
	csp_set_model(model);
	if (csp_init(SHIM_ADDR) != CSP_ERR_NONE)
		return;
	csp_kiss_init(&kiss_iface, &kiss_handle, kiss_putc, NULL, kiss_name);
	can_conf.ifc = can_name;
	if (csp_can_init(CSP_CAN_MASKED, &can_conf) != CSP_ERR_NONE)
		return;
	server_socket = csp_socket(CSP_SO_NONE);
	if (server_socket == NULL || csp_bind(server_socket, CSP_ANY) != CSP_ERR_NONE ||
	    csp_listen(server_socket, 10) != CSP_ERR_NONE)
		return;
	if (csp_route_start_task(0, 0) != CSP_ERR_NONE)
		return;
	if (pthread_create(&server, NULL, server_task, NULL) != 0)
		return;
	pthread_detach(server);
	init_result = 0;
}

/* Set libcsp up (once per process); 0 on success. */
int m6p_shim_init(void) {
	pthread_once(&init_once, init_once_fn);
	return init_result;
}

/* Our CSP address (the ping target). */
uint8_t m6p_shim_address(void) {
	return SHIM_ADDR;
}

/* A buffer holding `header` and `len` bytes of `data`, or NULL. */
static csp_packet_t *filled_packet(uint32_t header, const uint8_t *data, uint16_t len) {
	csp_packet_t *p = csp_buffer_get(len);
	if (p == NULL)
		return NULL;
	p->id.ext = header;
	memcpy(p->data, data, len);
	p->length = len;
	return p;
}

/* ---------------------------------------------------------------------------------------
 * Timed operations. */

/* KISS: see the file comment. The last frame goes to out[0..*out_len]. */
int64_t m6p_kiss_encode(uint32_t header, const uint8_t *data, uint16_t len, uint64_t iters,
			uint8_t *out, size_t cap, size_t *out_len) {
	if (m6p_shim_init() != 0)
		return SHIM_ERR_INIT;
	if (len > 256)
		return SHIM_ERR_ARG;
	pthread_mutex_lock(&op_lock);
	int64_t ret = 0;
	kiss_overflow = 0;
	int64_t start = now_ns();
	for (uint64_t i = 0; i < iters; i++) {
		csp_packet_t *p = filled_packet(header, data, len);
		if (p == NULL) {
			ret = SHIM_ERR_BUFFER;
			break;
		}
		kiss_len = 0;
		int r = kiss_iface.nexthop(&kiss_iface, p, 0);
		if (r != CSP_ERR_NONE) {
			ret = r < 0 ? r : SHIM_ERR_TX;
			break;
		}
	}
	int64_t elapsed = now_ns() - start;
	if (ret == 0 && kiss_overflow)
		ret = SHIM_ERR_OVERFLOW;
	if (ret == 0 && kiss_len > cap)
		ret = SHIM_ERR_ARG;
	if (ret == 0) {
		memcpy(out, kiss_out, kiss_len);
		*out_len = kiss_len;
		ret = elapsed;
	}
	pthread_mutex_unlock(&op_lock);
	return ret;
}

/* Send one packet with csp_can_tx and deliver every "transmit complete". */
static int run_can_tx(csp_packet_t *p) {
	can_count = 0;
	can_pending = 0;
	int r = csp_if_can.nexthop(&csp_if_can, p, 0);
	if (r != CSP_ERR_NONE)
		return r < 0 ? r : SHIM_ERR_TX;
	while (can_pending) {
		can_pending = 0;
		r = can_txcb(can_pending_id, CAN_NO_ERROR, NULL);
		if (r != CSP_ERR_NONE)
			return r < 0 ? r : SHIM_ERR_TX;
	}
	return 0;
}

/* CFP: see the file comment. The last packet's frames go to out[0..*n]. */
int64_t m6p_cfp_fragment(uint32_t header, const uint8_t *data, uint16_t len, uint64_t iters,
			 struct m6p_frame *out, size_t cap, size_t *n) {
	if (m6p_shim_init() != 0)
		return SHIM_ERR_INIT;
	if (len > 256)
		return SHIM_ERR_ARG;
	pthread_mutex_lock(&op_lock);
	int64_t ret = 0;
	int64_t start = now_ns();
	for (uint64_t i = 0; i < iters; i++) {
		csp_packet_t *p = filled_packet(header, data, len);
		if (p == NULL) {
			ret = SHIM_ERR_BUFFER;
			break;
		}
		int r = run_can_tx(p);
		if (r != 0) {
			ret = r;
			break;
		}
	}
	int64_t elapsed = now_ns() - start;
	if (ret == 0 && can_count > cap)
		ret = SHIM_ERR_ARG;
	if (ret == 0) {
		memcpy(out, can_out, can_count * sizeof can_out[0]);
		*n = can_count;
		ret = elapsed;
	}
	pthread_mutex_unlock(&op_lock);
	return ret;
}

/* CRC: `iters` calls of csp_crc32_memory; *crc is the value. */
int64_t m6p_crc32(const uint8_t *data, uint32_t len, uint64_t iters, uint32_t *crc) {
	if (m6p_shim_init() != 0)
		return SHIM_ERR_INIT;
	pthread_mutex_lock(&op_lock);
	uint32_t acc = 0, last = 0;
	int64_t start = now_ns();
	for (uint64_t i = 0; i < iters; i++) {
		last = csp_crc32_memory(data, len);
		acc ^= last;
	}
	int64_t elapsed = now_ns() - start;
	/* Keep the calls observable. */
	volatile uint32_t sink = acc;
	(void)sink;
	*crc = last;
	pthread_mutex_unlock(&op_lock);
	return elapsed;
}

/* ping: `iters` csp_ping calls to our own address; every one must be answered. */
int64_t m6p_ping(uint16_t len, uint32_t timeout_ms, uint64_t iters) {
	if (m6p_shim_init() != 0)
		return SHIM_ERR_INIT;
	if (len > 256)
		return SHIM_ERR_ARG;
	pthread_mutex_lock(&op_lock);
	int64_t ret = 0;
	int64_t start = now_ns();
	for (uint64_t i = 0; i < iters; i++) {
		if (csp_ping(SHIM_ADDR, timeout_ms, len, CSP_O_NONE) < 0) {
			ret = SHIM_ERR_PING;
			break;
		}
	}
	int64_t elapsed = now_ns() - start;
	if (ret == 0)
		ret = elapsed;
	pthread_mutex_unlock(&op_lock);
	return ret;
}

/* Buffer cycle: csp_buffer_get + copy + csp_buffer_free, `iters` times. */
int64_t m6p_buffer_cycle(const uint8_t *data, uint16_t len, uint64_t iters) {
	if (m6p_shim_init() != 0)
		return SHIM_ERR_INIT;
	if (len > 256)
		return SHIM_ERR_ARG;
	pthread_mutex_lock(&op_lock);
	int64_t ret = 0;
	int64_t start = now_ns();
	for (uint64_t i = 0; i < iters; i++) {
		csp_packet_t *p = filled_packet(0, data, len);
		if (p == NULL) {
			ret = SHIM_ERR_BUFFER;
			break;
		}
		csp_buffer_free(p);
	}
	int64_t elapsed = now_ns() - start;
	if (ret == 0)
		ret = elapsed;
	pthread_mutex_unlock(&op_lock);
	return ret;
}
