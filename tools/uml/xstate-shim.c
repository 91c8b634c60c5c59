/*
 * LD_PRELOAD shim for User-Mode Linux on hosts whose XSAVE area is larger
 * than the guest kernel expects (e.g. Intel CPUs with AMX: 11008 bytes).
 *
 * Debian bookworm's UML 6.1 saves/restores the guest's FPU state with
 * PTRACE_GETREGSET/PTRACE_SETREGSET(NT_X86_XSTATE) using a fixed 2696-byte
 * buffer (x87/SSE/AVX/AVX-512/PKRU).  Recent host kernels reject a
 * PTRACE_SETREGSET whose size is not exactly the host's full XSAVE size with
 * EFAULT, so UML dies at its first user process with
 *   "userspace - ptrace set fp regs failed, errno = 14".
 *
 * This shim pads such short SETREGSET buffers to the host size: the prefix
 * UML gave is copied verbatim, the tail is zeroed, and the components that
 * live in the tail (AMX tile config/data, which a UML guest can never enable)
 * are marked as being in their initial state in XSTATE_BV.  Every other
 * ptrace call is passed through unchanged.  Upstream Linux fixed this in UML
 * itself (dynamic FP register size), so with a newer UML the shim is a no-op.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <cpuid.h>

#ifndef NT_X86_XSTATE
#define NT_X86_XSTATE 0x202
#endif

#define XSAVE_HDR_OFFSET 512

typedef long (*ptrace_fn)(int, ...);

static ptrace_fn real_ptrace;
static size_t host_size;      /* full XSAVE size the host kernel insists on */
static unsigned char *padded; /* scratch buffer of host_size bytes */

static void init_host_size(void)
{
    unsigned int eax, ebx, ecx, edx;
    if (host_size)
        return;
    /* CPUID.(EAX=0DH,ECX=0):ECX = size of XSAVE area for all supported features. */
    if (!__get_cpuid_count(0xd, 0, &eax, &ebx, &ecx, &edx))
        return;
    host_size = ecx;
    padded = malloc(host_size);
    if (!padded)
        host_size = 0;
}

/* Clear XSTATE_BV bits of components that do not fit entirely in `len` bytes. */
static void clear_components_beyond(unsigned char *buf, size_t len)
{
    uint64_t bv;
    unsigned int eax, ebx, ecx, edx;
    memcpy(&bv, buf + XSAVE_HDR_OFFSET, sizeof bv);
    for (unsigned int i = 2; i < 63; i++) {
        if (!(bv & (1ULL << i)))
            continue;
        if (!__get_cpuid_count(0xd, i, &eax, &ebx, &ecx, &edx))
            continue;
        /* EAX = size, EBX = offset in the standard (non-compacted) format. */
        if ((size_t)ebx + eax > len)
            bv &= ~(1ULL << i);
    }
    memcpy(buf + XSAVE_HDR_OFFSET, &bv, sizeof bv);
}

long ptrace(enum __ptrace_request request, ...)
{
    va_list ap;
    va_start(ap, request);
    pid_t pid = va_arg(ap, pid_t);
    void *addr = va_arg(ap, void *);
    void *data = va_arg(ap, void *);
    va_end(ap);

    if (!real_ptrace)
        real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");

    if (request == PTRACE_SETREGSET && (uintptr_t)addr == NT_X86_XSTATE && data) {
        struct iovec *iov = data;
        init_host_size();
        if (host_size && iov->iov_len < host_size && iov->iov_len > XSAVE_HDR_OFFSET + 8) {
            struct iovec full = { padded, host_size };
            long r;
            memcpy(padded, iov->iov_base, iov->iov_len);
            memset(padded + iov->iov_len, 0, host_size - iov->iov_len);
            clear_components_beyond(padded, iov->iov_len);
            r = real_ptrace(request, pid, addr, &full);
            return r;
        }
    }
    return real_ptrace(request, pid, addr, data);
}
