/*
 * hilbench run's preload shim: a serial adapter's semantics on a bench's pseudo-terminals.
 *
 * A pty has no modem lines (TIOCMGET/TIOCMSET/TIOCMBIS/TIOCMBIC fail with ENOTTY),
 * no BREAK (accepted and ignored), and tcflush(TCOFLUSH) on it throws away bytes
 * the bench has not read yet, where a USB adapter has already put them on the
 * wire. Loaded with LD_PRELOAD into an unmodified client, this library takes those
 * calls on descriptors whose device number (st_rdev) is one of the bench's ptys
 * and asks the bench's line server instead (hilbench/bench/line_server.py has the
 * protocol): HILBENCH_RUN_PORTS="RDEV=SOCKET;RDEV=SOCKET...".
 *
 * glibc's tcflush, tcdrain, tcsendbreak, tcsetattr and tcgetattr call the system call
 * themselves, not ioctl(), so they are taken here too. Every other call, every
 * other descriptor, and every call the bench does not answer go to the real libc
 * (fail open: the client then sees what a plain pty does). One short connection
 * per call: no state shared between threads, nothing to repair after fork(), no
 * allocation; errno is kept unless the real call sets it.
 *
 * Built by hilbench/run/build.py with the system's cc on first use.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/un.h>
#include <termios.h>
#include <unistd.h>

#define MAX_PORTS 64
#define TIMEOUT_S 30

struct bench_port {
    dev_t rdev;
    char socket[sizeof(((struct sockaddr_un *)0)->sun_path)];
};

static struct bench_port ports[MAX_PORTS];
static int nports;
static pthread_once_t once = PTHREAD_ONCE_INIT;

static int (*real_ioctl)(int, unsigned long, ...);
static int (*real_tcflush)(int, int);
static int (*real_tcdrain)(int);
static int (*real_tcsendbreak)(int, int);
static int (*real_tcsetattr)(int, int, const struct termios *);
static int (*real_tcgetattr)(int, struct termios *);

/* struct termios2 of <asm/termbits.h>, which cannot be included beside <termios.h>. */
struct shim_termios2 {
    tcflag_t c_iflag, c_oflag, c_cflag, c_lflag;
    cc_t c_line;
    cc_t c_cc[19];
    speed_t c_ispeed, c_ospeed;
};
#define SHIM_TCGETS2 _IOR('T', 0x2A, struct shim_termios2)
#define SHIM_TCSETS2 _IOW('T', 0x2B, struct shim_termios2)
#define SHIM_TCSETSW2 _IOW('T', 0x2C, struct shim_termios2)
#define SHIM_TCSETSF2 _IOW('T', 0x2D, struct shim_termios2)

static void init(void)
{
    int saved = errno;
    real_ioctl = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    real_tcflush = (int (*)(int, int))dlsym(RTLD_NEXT, "tcflush");
    real_tcdrain = (int (*)(int))dlsym(RTLD_NEXT, "tcdrain");
    real_tcsendbreak = (int (*)(int, int))dlsym(RTLD_NEXT, "tcsendbreak");
    real_tcsetattr = (int (*)(int, int, const struct termios *))dlsym(RTLD_NEXT, "tcsetattr");
    real_tcgetattr = (int (*)(int, struct termios *))dlsym(RTLD_NEXT, "tcgetattr");
    const char *spec = getenv("HILBENCH_RUN_PORTS");
    while (spec && *spec && nports < MAX_PORTS) {
        const char *end = strchr(spec, ';');
        size_t len = end ? (size_t)(end - spec) : strlen(spec);
        const char *eq = memchr(spec, '=', len);
        if (eq) {
            char *after;
            unsigned long long rdev = strtoull(spec, &after, 10);
            size_t path_len = len - (size_t)(eq + 1 - spec);
            if (after == eq && after != spec && path_len > 0 && path_len < sizeof ports[0].socket) {
                ports[nports].rdev = (dev_t)rdev;
                memcpy(ports[nports].socket, eq + 1, path_len);
                ports[nports].socket[path_len] = '\0';
                nports++;
            }
        }
        spec = end ? end + 1 : NULL;
    }
    errno = saved;
}

/* The bench port behind fd, or NULL (not a character device, or not one of the bench's ptys). */
static const struct bench_port *bench_port(int fd)
{
    struct stat st;
    int saved = errno, i;
    pthread_once(&once, init);
    if (nports == 0 || fd < 0)
        return NULL;
    if (fstat(fd, &st) != 0 || !S_ISCHR(st.st_mode)) {
        errno = saved;
        return NULL;
    }
    for (i = 0; i < nports; i++)
        if (ports[i].rdev == st.st_rdev)
            return &ports[i];
    return NULL;
}

/* Sends "RDEV REQUEST" and reads the one-line answer; 0 and *value on "ok N", -1 on anything else. */
static int ask(const struct bench_port *p, const char *request, long *value, int timeout_s)
{
    char buf[256];
    struct sockaddr_un addr;
    struct timeval tv = {timeout_s, 0};
    int saved = errno, rc = -1, s, n;
    size_t off = 0, got = 0;

    n = snprintf(buf, sizeof buf, "%llu %s\n", (unsigned long long)p->rdev, request);
    if (n <= 0 || (size_t)n >= sizeof buf)
        goto out;
    s = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (s < 0)
        goto out;
    setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    setsockopt(s, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    memset(&addr, 0, sizeof addr);
    addr.sun_family = AF_UNIX;
    memcpy(addr.sun_path, p->socket, strlen(p->socket) + 1);
    while (connect(s, (struct sockaddr *)&addr, sizeof addr) != 0) {
        if (errno == EISCONN)
            break;
        if (errno != EINTR)
            goto done;
    }
    while (off < (size_t)n) {
        ssize_t w = send(s, buf + off, (size_t)n - off, MSG_NOSIGNAL);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            goto done;
        }
        off += (size_t)w;
    }
    while (got < sizeof buf - 1) {
        ssize_t r = recv(s, buf + got, sizeof buf - 1 - got, 0);
        if (r < 0) {
            if (errno == EINTR)
                continue;
            goto done;
        }
        if (r == 0)
            break;
        got += (size_t)r;
        if (memchr(buf + got - (size_t)r, '\n', (size_t)r))
            break;
    }
    buf[got] = '\0';
    if (strncmp(buf, "ok", 2) == 0 && (buf[2] == ' ' || buf[2] == '\n')) {
        if (value)
            *value = strtol(buf + 2, NULL, 10);
        rc = 0;
    }
done:
    close(s);
out:
    errno = saved;
    return rc;
}

static int ask_break(const struct bench_port *p, double seconds)
{
    char request[64];
    snprintf(request, sizeof request, "break %.3f", seconds);
    return ask(p, request, NULL, TIMEOUT_S + (int)seconds);
}

/* After the client's own tcsetattr: the bench re-reads the rate; the framing comes from the request
 * (a pty forces CS8 and clears PARENB). */
static void report_settings(const struct bench_port *p, tcflag_t cflag)
{
    char request[64];
    snprintf(request, sizeof request, "sync %lu", (unsigned long)cflag);
    ask(p, request, NULL, TIMEOUT_S);
}

/* A pty forgets data bits and parity (it forces CS8, clears PARENB): what a client reads back is what
 * it last set, remembered by the bench, so read-modify-write code (pyserial's custom rates) keeps it. */
#define FRAMING (CSIZE | PARENB | PARODD | CMSPAR | CSTOPB)
static void correct_framing(const struct bench_port *p, tcflag_t *cflag)
{
    long framing;
    if (ask(p, "framing", &framing, TIMEOUT_S) == 0 && framing >= 0)
        *cflag = (*cflag & ~(tcflag_t)FRAMING) | ((tcflag_t)framing & FRAMING);
}

/* tcflush semantics on a bench pty; -2: not handled, let the real call do it. */
static int flush_port(const struct bench_port *p, int fd, int queue)
{
    if (queue != TCOFLUSH && queue != TCIOFLUSH)
        return -2;
    if (ask(p, "flush", NULL, TIMEOUT_S) != 0)
        return -2;
    if (queue == TCIOFLUSH)
        return real_tcflush ? real_tcflush(fd, TCIFLUSH) : real_ioctl(fd, TCFLSH, TCIFLUSH);
    return 0;
}

int ioctl(int fd, unsigned long request, ...)
{
    va_list ap;
    void *arg;
    const struct bench_port *p;
    long value;
    int rc;

    va_start(ap, request);
    arg = va_arg(ap, void *);
    va_end(ap);
    pthread_once(&once, init);
    if (!real_ioctl) {
        errno = ENOSYS;
        return -1;
    }
    switch (request) {
    case TIOCMGET: case TIOCMSET: case TIOCMBIS: case TIOCMBIC:
    case TIOCSBRK: case TIOCCBRK: case TCSBRK: case TCSBRKP: case TCFLSH:
    case TCSETS: case TCSETSW: case TCSETSF: case SHIM_TCSETS2: case SHIM_TCSETSW2: case SHIM_TCSETSF2:
    case TCGETS: case SHIM_TCGETS2:
        break;
    default:
        return real_ioctl(fd, request, arg);
    }
    p = bench_port(fd);
    if (!p)
        return real_ioctl(fd, request, arg);
    switch (request) {
    case TIOCMGET:
        if (arg && ask(p, "mget", &value, TIMEOUT_S) == 0) {
            *(int *)arg = (int)value;
            return 0;
        }
        break;
    case TIOCMSET: case TIOCMBIS: case TIOCMBIC: {
        char text[32];
        const char *verb = request == TIOCMSET ? "mset" : request == TIOCMBIS ? "mbis" : "mbic";
        if (!arg)
            break;
        snprintf(text, sizeof text, "%s %d", verb, *(const int *)arg);
        if (ask(p, text, NULL, TIMEOUT_S) == 0)
            return 0;
        break;
    }
    case TIOCSBRK: case TIOCCBRK:
        if (ask(p, request == TIOCSBRK ? "break on" : "break off", NULL, TIMEOUT_S) == 0)
            return 0;
        break;
    case TCSBRK:  /* argument 0: a break of 0.25 s; otherwise tcdrain() */
        if ((intptr_t)arg == 0)
            return ask_break(p, 0.25) == 0 ? 0 : real_ioctl(fd, request, arg);
        ask(p, "drain", NULL, TIMEOUT_S);
        break;
    case TCSBRKP:  /* argument n: a break of n tenths of a second (0: 0.25 s) */
        if (ask_break(p, (intptr_t)arg > 0 ? (double)(intptr_t)arg / 10.0 : 0.25) == 0)
            return 0;
        break;
    case TCFLSH:
        rc = flush_port(p, fd, (int)(intptr_t)arg);
        if (rc != -2)
            return rc;
        break;
    case TCGETS: case SHIM_TCGETS2:
        rc = real_ioctl(fd, request, arg);
        if (rc == 0 && arg)  /* c_cflag is the third field of both structs */
            correct_framing(p, request == TCGETS ? &((struct termios *)arg)->c_cflag
                                                 : &((struct shim_termios2 *)arg)->c_cflag);
        return rc;
    default: {  /* TCSETS*: bytes written before go out at the old settings */
        tcflag_t cflag;
        if (!arg)
            break;
        cflag = request == TCSETS || request == TCSETSW || request == TCSETSF
                    ? ((const struct termios *)arg)->c_cflag
                    : ((const struct shim_termios2 *)arg)->c_cflag;
        ask(p, "drain", NULL, TIMEOUT_S);
        rc = real_ioctl(fd, request, arg);
        if (rc == 0)
            report_settings(p, cflag);
        return rc;
    }
    }
    return real_ioctl(fd, request, arg);
}

int tcflush(int fd, int queue)
{
    const struct bench_port *p = bench_port(fd);
    if (p) {
        int rc = flush_port(p, fd, queue);
        if (rc != -2)
            return rc;
    }
    if (!real_tcflush) {
        errno = ENOSYS;
        return -1;
    }
    return real_tcflush(fd, queue);
}

int tcdrain(int fd)
{
    const struct bench_port *p = bench_port(fd);
    if (p)
        ask(p, "drain", NULL, TIMEOUT_S);
    if (!real_tcdrain) {
        errno = ENOSYS;
        return -1;
    }
    return real_tcdrain(fd);
}

int tcsendbreak(int fd, int duration)
{
    const struct bench_port *p = bench_port(fd);
    /* glibc's meaning: 0 is 0.25 s, a positive duration is milliseconds rounded up to tenths. */
    if (p && ask_break(p, duration <= 0 ? 0.25 : (double)((duration + 99) / 100) / 10.0) == 0)
        return 0;
    if (!real_tcsendbreak) {
        errno = ENOSYS;
        return -1;
    }
    return real_tcsendbreak(fd, duration);
}

/* Debian's and Fedora's glibc read the settings back after TCSETS and fail with EINVAL when the
 * kernel changed PARENB or CSIZE, which a pty always does (it forces CS8, clears PARENB): a client
 * asking for 8E1 or 7 data bits cannot open a pty at all. An adapter takes them, so on a bench pty
 * the call succeeds when the kernel applied everything else; the bench hears the framing. */
static int pty_took_the_rest(int fd, tcflag_t wanted)
{
    struct termios got;
    const tcflag_t forced = CSIZE | PARENB | CREAD;
    int saved = errno;
    int same = real_tcgetattr && real_tcgetattr(fd, &got) == 0 && (got.c_cflag & ~forced) == (wanted & ~forced);
    errno = saved;
    return same;
}

int tcsetattr(int fd, int action, const struct termios *t)
{
    const struct bench_port *p = bench_port(fd);
    int rc;
    if (!real_tcsetattr) {
        errno = ENOSYS;
        return -1;
    }
    if (!p || !t)
        return real_tcsetattr(fd, action, t);
    ask(p, "drain", NULL, TIMEOUT_S);
    rc = real_tcsetattr(fd, action, t);
    if (rc != 0 && errno == EINVAL && pty_took_the_rest(fd, t->c_cflag))
        rc = 0;
    if (rc == 0)
        report_settings(p, t->c_cflag);
    return rc;
}

int tcgetattr(int fd, struct termios *t)
{
    const struct bench_port *p = bench_port(fd);
    int rc;
    if (!real_tcgetattr) {
        errno = ENOSYS;
        return -1;
    }
    rc = real_tcgetattr(fd, t);
    if (rc == 0 && p && t)
        correct_framing(p, &t->c_cflag);
    return rc;
}
