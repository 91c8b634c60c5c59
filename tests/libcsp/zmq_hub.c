/* zmq_hub: the hub in the middle of libcsp 1.4's ZMQ interface (csp_if_zmqhub.c), for
 * testing the programs against each other without the twin.
 *
 *   zmq_hub HOST [SECONDS]
 *
 * Every libcsp node connects its PUB socket to tcp://HOST:6000 and its SUB socket to
 * tcp://HOST:7000 (ports fixed by libcsp 1.4). The hub binds an XSUB socket on the first
 * and an XPUB socket on the second and forwards everything both ways with zmq_proxy:
 * messages downstream, subscriptions (each node subscribes to its own address byte)
 * upstream. To run several hubs on one machine give each its own loopback address
 * (127.0.0.2, 127.0.0.3, ...), since the ports cannot change.
 *
 * It prints `hub HOST` on stdout once both sockets are bound, and runs until killed, or
 * for SECONDS if given. Exit status 0, or 2 if it cannot bind.
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include <zmq.h>

int main(int argc, char **argv) {
	if (argc < 2 || argc > 3) {
		fprintf(stderr, "usage: zmq_hub HOST [SECONDS]\n");
		return 2;
	}
	char in[256], out[256];
	snprintf(in, sizeof in, "tcp://%s:6000", argv[1]);
	snprintf(out, sizeof out, "tcp://%s:7000", argv[1]);

	void *ctx = zmq_ctx_new();
	void *xsub = zmq_socket(ctx, ZMQ_XSUB);
	void *xpub = zmq_socket(ctx, ZMQ_XPUB);
	if (ctx == NULL || xsub == NULL || xpub == NULL) {
		fprintf(stderr, "zmq_hub: %s\n", zmq_strerror(zmq_errno()));
		return 2;
	}
	if (zmq_bind(xsub, in) != 0) {
		fprintf(stderr, "zmq_hub: bind %s: %s\n", in, zmq_strerror(zmq_errno()));
		return 2;
	}
	if (zmq_bind(xpub, out) != 0) {
		fprintf(stderr, "zmq_hub: bind %s: %s\n", out, zmq_strerror(zmq_errno()));
		return 2;
	}
	printf("hub %s\n", argv[1]);
	fflush(stdout);
	if (argc == 3) {
		/* The default SIGALRM action ends the process: enough for a bounded test hub. */
		int s = atoi(argv[2]);
		if (s > 0)
			alarm((unsigned)s);
	}
	zmq_proxy(xsub, xpub, NULL); /* returns only when the context is terminated */
	zmq_close(xsub);
	zmq_close(xpub);
	zmq_ctx_term(ctx);
	return 0;
}
