/*
 * hilbench run's preload shim: a serial adapter's semantics on a bench's pseudo-terminals.
 *
 * A pty has no modem lines (TIOCMGET/TIOCMSET/TIOCMBIS/TIOCMBIC fail with ENOTTY),
 * no BREAK (accepted and ignored), and tcflush(TCOFLUSH) on it throws away bytes
 * the bench has not read yet, where a USB adapter has already put them on the
 * wire. Loaded with LD_PRELOAD into an unmodified client, this library takes those
 * calls on descriptors whose device number (st_rdev) is one of the bench's ptys
 * and asks the bench's port-state server instead (hilbench/bench/port_state_server.py has the
 * protocol): HILBENCH_RUN_PORTS="RDEV=SOCKET;RDEV=SOCKET...".
 *
 * glibc's tcflush, tcdrain, tcsendbreak, tcsetattr and tcgetattr call the system call
 * themselves, not ioctl(), so they are taken here too. Every other call, every
 * other descriptor, and every call the bench does not answer go to the real libc
 * (fail open: the client then sees what a plain pty does). errno is kept unless
 * the real call sets it.
 *
 * A drain (tcdrain, TCSBRK n, and the drain before a settings change) with nothing
 * pending must cost what it costs on an adapter with an empty queue: nothing.
 * dynamixel-sdk 3.x drains before every packet. So writes to bench ptys are
 * stamped on the bench's delivery ledger (hilbench/bench/delivery_ledger.py, a
 * shared page beside the socket): a drain asks the bench only if something
 * written before the last stamp may not be delivered yet. An output flush also
 * asks if this process wrote since its last drain or flush (the devices then hear
 * OutputFlushed). To see writes cheaply, the bench port behind each descriptor is
 * cached (fstat on first use), forgotten when the descriptor is closed, replaced
 * or opened again; stdio cannot be seen (glibc writes its buffers without calling
 * write()), so a bench pty used through a FILE or as fd 0-2 makes every drain ask.
 *
 * Requests reuse connections from a small pool (a connect and a server thread per
 * request cost more than the request); a forked child drops the parent's.
 *
 * Built by hilbench/run/build.py with the system's cc on first use.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdarg.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <sys/sendfile.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/uio.h>
#include <sys/un.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define MAX_PORTS 64
#define MAX_SOCKETS 16
#define TIMEOUT_S 30
#define FD_CACHE 65536  /* descriptors above are looked up on every call */
#define POOL_MAX 8

/* The delivery ledger (hilbench/bench/delivery_ledger.py): a header, then one slot per pty. */
#define LEDGER_MAGIC "HBLEDGR1"
#define LEDGER_VERSION 1
#define LEDGER_HEADER 64
struct ledger_slot {
    uint64_t rdev;
    uint64_t idle_ns;      /* the bench: everything stamped before this CLOCK_MONOTONIC time is delivered */
    uint64_t dirty_ns;     /* C writers (an atomic maximum): the clock as the last write() began */
    uint64_t dirty_py_ns;  /* the same for the Python fallback's writers */
    uint64_t writing;      /* C writers: write() calls under way (the bench waits for none) */
    uint64_t writing_py;   /* the Python fallback's: 1 while one is under way */
    uint64_t drain_ns;     /* clients: the clock at their last drain (the bench then looks again for them) */
    uint64_t reserved[1];
};

struct bench_socket {
    char path[sizeof(((struct sockaddr_un *)0)->sun_path)];
};

/* The serving rings (hilbench/bench/serve_ring.py; on with a virtual clock, on the wall clock with
 * HILBENCH_SERVE=1): a header, then per pty a record and its ring of device->host bytes. */
#define SERVE_MAGIC "HBSERVE1"
#define SERVE_VERSION 1
#define SERVE_HEADER 64
#define SERVE_RING 65536
enum { SERVE_KERNEL, SERVE_SERVED, SERVE_FALLBACK };
struct serve_rec {
    uint64_t rdev;
    uint64_t mode;     /* the bench: kernel, served (bytes go to the ring), fallback (to the pty, for good) */
    uint64_t head;     /* the bench: bytes appended since the start */
    uint64_t tail;     /* clients (compare-and-swap): bytes taken */
    uint64_t waiters;  /* clients blocked on the FIFO serve.<index> (the bench writes a byte to it then) */
    uint64_t dropped;
    uint64_t reserved[2];
    unsigned char data[SERVE_RING];
};

struct bench_port {
    dev_t rdev;
    int sock;                 /* index into sockets[] */
    struct ledger_slot *slot;  /* NULL: the bench has no ledger; every drain asks */
    int wrote;                /* this process wrote since its last drain or output flush */
    int unseen;               /* this process may write to it where we cannot see (stdio): always ask */
    struct serve_rec *ring;   /* its serving ring (HILBENCH_SERVE=1 and the bench has one), else NULL */
    int ring_index;           /* the record's index: the FIFO's name */
    int claimed;              /* this process asked the bench to serve it (once) */
    int refused;              /* this process uses it where the ring cannot answer (epoll, stdio): never ask */
    int fifo;                 /* the wake FIFO's read end, opened on first wait (0: not yet, -1: failed) */
};
static int serving;  /* HILBENCH_SERVE=1 */

static struct bench_port ports[MAX_PORTS];
static int nports;
static struct bench_socket sockets[MAX_SOCKETS];
static int nsockets;
static pthread_once_t once = PTHREAD_ONCE_INIT;
static int ready;                /* init() is done */
static __thread int initializing; /* this thread runs init(): a signal handler's write() must not wait for it */

/* fd -> 0: not looked up, 1: not a bench pty, 2 + i: ports[i]. */
static unsigned char fd_port[FD_CACHE];

static int (*real_ioctl)(int, unsigned long, ...);
static int (*real_tcflush)(int, int);
static int (*real_tcdrain)(int);
static int (*real_tcsendbreak)(int, int);
static int (*real_tcsetattr)(int, int, const struct termios *);
static int (*real_tcgetattr)(int, struct termios *);
static ssize_t (*real_write)(int, const void *, size_t);
static ssize_t (*real_writev)(int, const struct iovec *, int);
static ssize_t (*real_sendfile)(int, int, off_t *, size_t);
static ssize_t (*real_sendfile64)(int, int, off64_t *, size_t);
static ssize_t (*real_splice)(int, off64_t *, int, off64_t *, size_t, unsigned int);
static int (*real_vdprintf)(int, const char *, va_list);
static int (*real___vdprintf_chk)(int, int, const char *, va_list);
static int (*real_close)(int);
static int (*real_close_range)(unsigned int, unsigned int, int);
static void (*real_closefrom)(int);
static int (*real_dup)(int);
static int (*real_dup2)(int, int);
static int (*real_dup3)(int, int, int);
static int (*real_fcntl)(int, int, ...);
static int (*real_fcntl64)(int, int, ...);
static int (*real_open)(const char *, int, ...);
static int (*real_open64)(const char *, int, ...);
static int (*real_openat)(int, const char *, int, ...);
static int (*real_openat64)(int, const char *, int, ...);
static int (*real___open_2)(const char *, int);
static int (*real___open64_2)(const char *, int);
static FILE *(*real_fopen)(const char *, const char *);
static FILE *(*real_fopen64)(const char *, const char *);
static FILE *(*real_fdopen)(int, const char *);
static FILE *(*real_freopen)(const char *, const char *, FILE *);
static FILE *(*real_freopen64)(const char *, const char *, FILE *);
static int (*real_fclose)(FILE *);

/* vclock.c, built into the same library: the real clock (ledger stamps are in the bench's real time,
 * also when the client's clock is virtual), the end of a descriptor, and every write. */
__attribute__((visibility("hidden"))) int hb_real_clock_gettime(clockid_t clk, struct timespec *tp);
__attribute__((visibility("hidden"))) void hb_vclock_forget(int fd);
__attribute__((visibility("hidden"))) void hb_vclock_wrote(int fd, ssize_t n);
__attribute__((visibility("hidden"))) void hb_vclock_flushing(int fd, int queue);
__attribute__((visibility("hidden"))) int hb_vclock_empty(int fd);
static void hb_serve_flush(int fd, int queue);
__attribute__((visibility("hidden"))) void hb_serve_refuse(int fd);
__attribute__((visibility("hidden"))) int hb_serve_inq(int fd, int *value);

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

/* ------------------------------------------------------------------ connections to port-state servers */

struct conn {
    int fd, sock, timeout;
};
static struct conn pool[POOL_MAX];
static int npool;
static pthread_mutex_t pool_lock = PTHREAD_MUTEX_INITIALIZER;

static void close_fd(int fd)
{
    if (real_close)
        real_close(fd);
    else
        syscall(SYS_close, fd);
}

/* A kept connection to socket `sock`, or -1. trylock: never block (a drain may run in a signal handler). */
static int pool_take(int sock, struct conn *c)
{
    int i, found = -1;
    if (pthread_mutex_trylock(&pool_lock) != 0)
        return -1;
    for (i = npool - 1; i >= 0; i--)
        if (pool[i].sock == sock) {
            *c = pool[i];
            pool[i] = pool[--npool];
            found = 0;
            break;
        }
    pthread_mutex_unlock(&pool_lock);
    return found;
}

static void pool_put(const struct conn *c)
{
    if (pthread_mutex_trylock(&pool_lock) == 0) {
        if (npool < POOL_MAX) {
            pool[npool++] = *c;
            pthread_mutex_unlock(&pool_lock);
            return;
        }
        pthread_mutex_unlock(&pool_lock);
    }
    close_fd(c->fd);
}

static void before_fork(void) { pthread_mutex_lock(&pool_lock); }
static void after_fork_parent(void) { pthread_mutex_unlock(&pool_lock); }

/* The child's copies of the parent's connections: one request at a time per connection, so they
 * are the parent's alone (closing the copies leaves the parent's open). */
static void after_fork_child(void)
{
    int i;
    for (i = 0; i < npool; i++)
        close_fd(pool[i].fd);
    npool = 0;
    pthread_mutex_init(&pool_lock, NULL);
}

static void set_timeout(struct conn *c, int timeout_s)
{
    struct timeval tv = {timeout_s, 0};
    if (c->timeout == timeout_s)
        return;
    setsockopt(c->fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    setsockopt(c->fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    c->timeout = timeout_s;
}

/* A new connection (timeouts set before connect: a full backlog must not block forever); -1 on failure. */
static int connect_to(struct conn *c, int sock, int timeout_s)
{
    struct sockaddr_un addr;
    int s = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (s < 0)
        return -1;
    c->fd = s;
    c->sock = sock;
    c->timeout = 0;
    set_timeout(c, timeout_s);
    memset(&addr, 0, sizeof addr);
    addr.sun_family = AF_UNIX;
    memcpy(addr.sun_path, sockets[sock].path, strlen(sockets[sock].path) + 1);
    while (connect(s, (struct sockaddr *)&addr, sizeof addr) != 0) {
        if (errno == EISCONN)
            break;
        if (errno != EINTR) {
            close_fd(s);
            return -1;
        }
    }
    return 0;
}

/* Sends "RDEV REQUEST" and reads the one-line answer; 0 and *value on "ok N", -1 on anything else. */
static int ask(const struct bench_port *p, const char *request, long *value, int timeout_s)
{
    char line[256], buf[256];
    int saved = errno, rc = -1, n, attempt;

    n = snprintf(line, sizeof line, "%llu %s\n", (unsigned long long)p->rdev, request);
    if (n <= 0 || (size_t)n >= sizeof line)
        goto out;
    for (attempt = 0; attempt < 2; attempt++) {
        struct conn c;
        size_t off = 0, got = 0;
        int reused = pool_take(p->sock, &c) == 0, stale = 0;
        if (!reused && connect_to(&c, p->sock, timeout_s) != 0)
            goto out;
        set_timeout(&c, timeout_s);
        while (off < (size_t)n) {
            ssize_t w = send(c.fd, line + off, (size_t)n - off, MSG_NOSIGNAL);
            if (w < 0) {
                if (errno == EINTR)
                    continue;
                stale = errno == EPIPE || errno == ECONNRESET;
                break;
            }
            off += (size_t)w;
        }
        while (off == (size_t)n && got < sizeof buf - 1) {
            ssize_t r = recv(c.fd, buf + got, sizeof buf - 1 - got, 0);
            if (r < 0) {
                if (errno == EINTR)
                    continue;
                stale = got == 0 && errno == ECONNRESET;
                break;  /* a timeout is no reason to send it again */
            }
            if (r == 0) {
                stale = got == 0;
                break;
            }
            got += (size_t)r;
            if (memchr(buf + got - (size_t)r, '\n', (size_t)r))
                break;
        }
        if (got == 0 || buf[got - 1] != '\n') {
            close_fd(c.fd);
            if (reused && stale)
                continue;  /* a kept connection the server had closed (it stopped or restarted): once more, anew */
            goto out;
        }
        buf[got] = '\0';
        pool_put(&c);
        if (strncmp(buf, "ok", 2) == 0 && (buf[2] == ' ' || buf[2] == '\n')) {
            if (value)
                *value = strtol(buf + 2, NULL, 10);
            rc = 0;
        }
        break;
    }
out:
    errno = saved;
    return rc;
}

/* ------------------------------------------------------------------ which descriptors are bench ptys */

/* The records of a table the bench keeps beside its port-state socket (``name``: port_state.ledger or
 * port_state.serve), mapped shared, once its header checks out (magic, version, record size, a count
 * that fits the file); NULL otherwise. *count: its records. */
static unsigned char *map_table(int sock, const char *name, const char *magic, uint64_t version, size_t header,
                                size_t record, uint64_t *count)
{
    char path[sizeof sockets[0].path + 16];
    const char *slash = strrchr(sockets[sock].path, '/');
    struct stat st;
    unsigned char *page;
    uint64_t n;
    int fd;

    if (!slash || !real_open)
        return NULL;
    snprintf(path, sizeof path, "%.*s/%s", (int)(slash - sockets[sock].path), sockets[sock].path, name);
    fd = real_open(path, O_RDWR | O_CLOEXEC);
    if (fd < 0)
        return NULL;
    if (fstat(fd, &st) != 0 || st.st_size < (off_t)header) {
        close_fd(fd);
        return NULL;
    }
    page = mmap(NULL, (size_t)st.st_size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    close_fd(fd);
    if (page == MAP_FAILED)
        return NULL;
    n = ((uint64_t *)page)[2];
    if (memcmp(page, magic, 8) != 0 || ((uint64_t *)page)[1] != version || ((uint64_t *)page)[3] != record ||
        n > 4096 || header + n * record > (uint64_t)st.st_size) {
        munmap(page, (size_t)st.st_size);
        return NULL;
    }
    *count = n;
    return page + header;
}

static void map_ledger(int sock)
{
    uint64_t nslots, i;
    struct ledger_slot *slots = (struct ledger_slot *)map_table(sock, "port_state.ledger", LEDGER_MAGIC,
                                                                LEDGER_VERSION, LEDGER_HEADER,
                                                                sizeof(struct ledger_slot), &nslots);
    int j;

    if (!slots)
        return;
    for (i = 0; i < nslots; i++)
        for (j = 0; j < nports; j++)
            if (ports[j].sock == sock && (uint64_t)ports[j].rdev == slots[i].rdev)
                ports[j].slot = &slots[i];
}

static void map_serve(int sock)
{
    uint64_t nrec, i;
    struct serve_rec *recs = (struct serve_rec *)map_table(sock, "port_state.serve", SERVE_MAGIC, SERVE_VERSION,
                                                           SERVE_HEADER, sizeof(struct serve_rec), &nrec);
    int j;

    if (!recs)
        return;
    for (i = 0; i < nrec; i++)
        for (j = 0; j < nports; j++)
            if (ports[j].sock == sock && (uint64_t)ports[j].rdev == recs[i].rdev) {
                ports[j].ring = &recs[i];
                ports[j].ring_index = (int)i;
            }
}

static int lookup(int fd)
{
    struct stat st;
    int i;
    if (fstat(fd, &st) != 0)
        return -2;  /* not open: nothing to remember */
    if (S_ISCHR(st.st_mode))
        for (i = 0; i < nports; i++)
            if (ports[i].rdev == st.st_rdev)
                return i;
    return -1;
}

/* A bench pty as fd 0-2 is written by stdio (printf), which we cannot see: its drains always ask. */
static void watch_stdio(int fd)
{
    int saved = errno, i;
    if (fd >= 0 && fd <= 2 && nports && (i = lookup(fd)) >= 0)
        __atomic_store_n(&ports[i].unseen, 1, __ATOMIC_SEQ_CST);
    errno = saved;
}

#define RESOLVE(name) real_##name = (__typeof__(real_##name))dlsym(RTLD_NEXT, #name)

static void init(void)
{
    int saved = errno, i, fd;
    initializing = 1;
    RESOLVE(ioctl); RESOLVE(tcflush); RESOLVE(tcdrain); RESOLVE(tcsendbreak); RESOLVE(tcsetattr);
    RESOLVE(tcgetattr); RESOLVE(write); RESOLVE(writev); RESOLVE(sendfile); RESOLVE(sendfile64);
    RESOLVE(splice); RESOLVE(vdprintf); RESOLVE(__vdprintf_chk); RESOLVE(close); RESOLVE(close_range);
    RESOLVE(closefrom); RESOLVE(dup); RESOLVE(dup2); RESOLVE(dup3); RESOLVE(fcntl); RESOLVE(fcntl64);
    RESOLVE(open); RESOLVE(open64); RESOLVE(openat); RESOLVE(openat64); RESOLVE(__open_2);
    RESOLVE(__open64_2); RESOLVE(fopen); RESOLVE(fopen64); RESOLVE(fdopen); RESOLVE(freopen);
    RESOLVE(freopen64); RESOLVE(fclose);
    const char *spec = getenv("HILBENCH_RUN_PORTS");
    while (spec && *spec && nports < MAX_PORTS) {
        const char *end = strchr(spec, ';');
        size_t len = end ? (size_t)(end - spec) : strlen(spec);
        const char *eq = memchr(spec, '=', len);
        if (eq) {
            char *after;
            unsigned long long rdev = strtoull(spec, &after, 10);
            size_t path_len = len - (size_t)(eq + 1 - spec);
            if (after == eq && after != spec && path_len > 0 && path_len < sizeof sockets[0].path) {
                for (i = 0; i < nsockets; i++)
                    if (strlen(sockets[i].path) == path_len && memcmp(sockets[i].path, eq + 1, path_len) == 0)
                        break;
                if (i == nsockets && nsockets < MAX_SOCKETS) {
                    memcpy(sockets[i].path, eq + 1, path_len);
                    sockets[i].path[path_len] = '\0';
                    nsockets++;
                }
                if (i < nsockets) {
                    ports[nports].rdev = (dev_t)rdev;
                    ports[nports].sock = i;
                    nports++;
                }
            }
        }
        spec = end ? end + 1 : NULL;
    }
    for (i = 0; i < nsockets; i++)
        map_ledger(i);
    /* The serving path: on with a virtual clock unless HILBENCH_SERVE=0, on the wall clock only with 1. */
    spec = getenv("HILBENCH_SERVE");
    serving = spec && *spec ? strcmp(spec, "1") == 0 : getenv("HILBENCH_CLOCK") != NULL;
    for (i = 0; serving && i < nsockets; i++)
        map_serve(i);
    if (nports) {
        pthread_atfork(before_fork, after_fork_parent, after_fork_child);
        for (fd = 0; fd <= 2; fd++)
            watch_stdio(fd);
    }
    __atomic_store_n(&ready, 1, __ATOMIC_RELEASE);
    initializing = 0;
    errno = saved;
}

/* init() once; 0 if this very thread is inside it (a signal handler interrupted it): bypass the shim. */
static int started(void)
{
    if (__atomic_load_n(&ready, __ATOMIC_ACQUIRE))
        return 1;
    if (initializing)
        return 0;
    pthread_once(&once, init);
    return 1;
}

/* The bench port behind fd, or NULL (not open, not a character device, not one of the bench's ptys). */
static struct bench_port *bench_port(int fd)
{
    unsigned char known;
    int saved, i;
    if (!started() || nports == 0 || fd < 0)
        return NULL;
    if (fd < FD_CACHE && (known = __atomic_load_n(&fd_port[fd], __ATOMIC_RELAXED)) != 0)
        return known == 1 ? NULL : &ports[known - 2];
    saved = errno;
    i = lookup(fd);
    errno = saved;
    if (i == -2)
        return NULL;
    if (fd < FD_CACHE)
        __atomic_store_n(&fd_port[fd], (unsigned char)(i < 0 ? 1 : i + 2), __ATOMIC_RELAXED);
    return i < 0 ? NULL : &ports[i];
}

/* fd is closed, replaced or new: look it up again on next use. */
static void forget(int fd)
{
    hb_vclock_forget(fd);
    if (fd >= 0 && fd < FD_CACHE)
        __atomic_store_n(&fd_port[fd], 0, __ATOMIC_RELAXED);
}

static void opened(int fd)
{
    forget(fd);
    if (fd >= 0 && fd <= 2)
        watch_stdio(fd);
}

static void opened_stream(FILE *f)
{
    int saved = errno, fd = f ? fileno(f) : -1, i;
    forget(fd);
    if (fd >= 0 && nports && (i = lookup(fd)) >= 0) {
        __atomic_store_n(&ports[i].unseen, 1, __ATOMIC_SEQ_CST);
        hb_serve_refuse(fd);  /* stdio reads with glibc's internal read(): the ring cannot answer them */
    }
    errno = saved;
}

/* ------------------------------------------------------------------ writes and drains */

static uint64_t now_ns(void)
{
    struct timespec ts;
    hb_real_clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* Before a write: counted (the bench waits until it returned), then stamped. A stamp taken after it
 * returned would do without the count, but the bench thread the write wakes often preempts the writer
 * right there and checks before the stamp; then every such drain would have to ask. */
static void write_begins(struct bench_port *p)
{
    __atomic_store_n(&p->wrote, 1, __ATOMIC_SEQ_CST);
    if (p->slot) {
        uint64_t now, cur;
        __atomic_add_fetch(&p->slot->writing, 1, __ATOMIC_SEQ_CST);
        now = now_ns();
        cur = __atomic_load_n(&p->slot->dirty_ns, __ATOMIC_RELAXED);
        while (cur < now && !__atomic_compare_exchange_n(&p->slot->dirty_ns, &cur, now, 1, __ATOMIC_SEQ_CST,
                                                         __ATOMIC_RELAXED))
            ;
    }
}

static void write_ends(struct bench_port *p)
{
    if (p->slot)
        __atomic_sub_fetch(&p->slot->writing, 1, __ATOMIC_SEQ_CST);
}

/* Everything written to the pty (by this process, and by others as far as the ledger knows) is delivered. */
static int delivered(struct bench_port *p)
{
    uint64_t idle, dirty, dirty_py;
    if (!p->slot)
        return 0;
    __atomic_store_n(&p->slot->drain_ns, now_ns(), __ATOMIC_RELAXED);  /* someone drains: keep it fresh */
    if (__atomic_load_n(&p->unseen, __ATOMIC_SEQ_CST))
        return 0;
    dirty = __atomic_load_n(&p->slot->dirty_ns, __ATOMIC_SEQ_CST);
    dirty_py = __atomic_load_n(&p->slot->dirty_py_ns, __ATOMIC_SEQ_CST);
    idle = __atomic_load_n(&p->slot->idle_ns, __ATOMIC_SEQ_CST);
    return idle > dirty && idle > dirty_py;
}

/* tcdrain semantics: returns once what was written is delivered; nothing to ask when it already is. */
static void drain_port(struct bench_port *p)
{
    __atomic_store_n(&p->wrote, 0, __ATOMIC_SEQ_CST);
    if (!delivered(p))
        ask(p, "drain", NULL, TIMEOUT_S);
}

#define WRAP_WRITE(fd, call)                   \
    do {                                       \
        struct bench_port *p_ = bench_port(fd); \
        ssize_t rc_;                           \
        int saved_;                            \
        if (p_)                                \
            write_begins(p_);                  \
        rc_ = call;                            \
        saved_ = errno;                        \
        if (p_)                                \
            write_ends(p_);                    \
        hb_vclock_wrote(fd, rc_);              \
        errno = saved_;                        \
        return rc_;                            \
    } while (0)

ssize_t write(int fd, const void *buf, size_t count)
{
    if (!started() || !real_write)
        return syscall(SYS_write, fd, buf, count);
    WRAP_WRITE(fd, real_write(fd, buf, count));
}

ssize_t writev(int fd, const struct iovec *iov, int iovcnt)
{
    if (!started() || !real_writev)
        return syscall(SYS_writev, fd, iov, iovcnt);
    WRAP_WRITE(fd, real_writev(fd, iov, iovcnt));
}

ssize_t sendfile(int out_fd, int in_fd, off_t *offset, size_t count)
{
    pthread_once(&once, init);
    if (!real_sendfile) {
        errno = ENOSYS;
        return -1;
    }
    WRAP_WRITE(out_fd, real_sendfile(out_fd, in_fd, offset, count));
}

ssize_t sendfile64(int out_fd, int in_fd, off64_t *offset, size_t count)
{
    pthread_once(&once, init);
    if (!real_sendfile64) {
        errno = ENOSYS;
        return -1;
    }
    WRAP_WRITE(out_fd, real_sendfile64(out_fd, in_fd, offset, count));
}

ssize_t splice(int fd_in, off64_t *off_in, int fd_out, off64_t *off_out, size_t len, unsigned int flags)
{
    pthread_once(&once, init);
    if (!real_splice) {
        errno = ENOSYS;
        return -1;
    }
    WRAP_WRITE(fd_out, real_splice(fd_in, off_in, fd_out, off_out, len, flags));
}

int vdprintf(int fd, const char *format, va_list ap)
{
    pthread_once(&once, init);
    if (!real_vdprintf) {
        errno = ENOSYS;
        return -1;
    }
    WRAP_WRITE(fd, real_vdprintf(fd, format, ap));
}

int dprintf(int fd, const char *format, ...)
{
    va_list ap;
    int rc;
    va_start(ap, format);
    rc = vdprintf(fd, format, ap);
    va_end(ap);
    return rc;
}

int __vdprintf_chk(int fd, int flag, const char *format, va_list ap)
{
    pthread_once(&once, init);
    if (!real___vdprintf_chk)
        return vdprintf(fd, format, ap);
    WRAP_WRITE(fd, real___vdprintf_chk(fd, flag, format, ap));
}

int __dprintf_chk(int fd, int flag, const char *format, ...)
{
    va_list ap;
    int rc;
    va_start(ap, format);
    rc = __vdprintf_chk(fd, flag, format, ap);
    va_end(ap);
    return rc;
}

/* ------------------------------------------------------------------ descriptors opened, copied, closed */

int close(int fd)
{
    int rc;
    if (!started())
        return (int)syscall(SYS_close, fd);
    forget(fd);
    rc = real_close ? real_close(fd) : (int)syscall(SYS_close, fd);
    forget(fd);  /* in case another thread looked it up in between */
    return rc;
}

int close_range(unsigned int first, unsigned int last, int flags)
{
    unsigned int fd;
    int rc;
    pthread_once(&once, init);
    if (!real_close_range) {
        errno = ENOSYS;
        return -1;
    }
    rc = real_close_range(first, last, flags);
    for (fd = first; fd <= last && fd < FD_CACHE; fd++)
        forget((int)fd);
    return rc;
}

void closefrom(int lowfd)
{
    int fd;
    pthread_once(&once, init);
    if (real_closefrom)
        real_closefrom(lowfd);
    for (fd = lowfd < 0 ? 0 : lowfd; fd < FD_CACHE; fd++)
        forget(fd);
}

int dup(int oldfd)
{
    int rc;
    pthread_once(&once, init);
    rc = real_dup(oldfd);
    forget(rc);
    return rc;
}

int dup2(int oldfd, int newfd)
{
    int rc;
    pthread_once(&once, init);
    rc = real_dup2(oldfd, newfd);
    if (rc >= 0)
        opened(newfd);
    return rc;
}

int dup3(int oldfd, int newfd, int flags)
{
    int rc;
    pthread_once(&once, init);
    rc = real_dup3(oldfd, newfd, flags);
    if (rc >= 0)
        opened(newfd);
    return rc;
}

static int fcntl_common(int (*real)(int, int, ...), int fd, int cmd, void *arg)
{
    int rc = real(fd, cmd, arg);
    if (rc >= 0 && (cmd == F_DUPFD || cmd == F_DUPFD_CLOEXEC))
        opened(rc);
    return rc;
}

int fcntl(int fd, int cmd, ...)
{
    va_list ap;
    void *arg;
    va_start(ap, cmd);
    arg = va_arg(ap, void *);  /* as glibc's own fcntl reads it: an int or a pointer, one register */
    va_end(ap);
    pthread_once(&once, init);
    return fcntl_common(real_fcntl, fd, cmd, arg);
}

int fcntl64(int fd, int cmd, ...)
{
    va_list ap;
    void *arg;
    va_start(ap, cmd);
    arg = va_arg(ap, void *);
    va_end(ap);
    pthread_once(&once, init);
    return fcntl_common(real_fcntl64 ? real_fcntl64 : real_fcntl, fd, cmd, arg);
}

#define OPEN_MODE(flags, mode)                                  \
    do {                                                        \
        mode = 0;                                               \
        if ((flags) & (O_CREAT | __O_TMPFILE)) {                \
            va_list ap_;                                        \
            va_start(ap_, flags);                               \
            mode = va_arg(ap_, mode_t);                         \
            va_end(ap_);                                        \
        }                                                       \
    } while (0)

int open(const char *path, int flags, ...)
{
    mode_t mode;
    int fd;
    OPEN_MODE(flags, mode);
    pthread_once(&once, init);
    fd = real_open(path, flags, mode);
    opened(fd);
    return fd;
}

int open64(const char *path, int flags, ...)
{
    mode_t mode;
    int fd;
    OPEN_MODE(flags, mode);
    pthread_once(&once, init);
    fd = (real_open64 ? real_open64 : real_open)(path, flags, mode);
    opened(fd);
    return fd;
}

int openat(int dirfd, const char *path, int flags, ...)
{
    mode_t mode;
    int fd;
    OPEN_MODE(flags, mode);
    pthread_once(&once, init);
    fd = real_openat(dirfd, path, flags, mode);
    opened(fd);
    return fd;
}

int openat64(int dirfd, const char *path, int flags, ...)
{
    mode_t mode;
    int fd;
    OPEN_MODE(flags, mode);
    pthread_once(&once, init);
    fd = (real_openat64 ? real_openat64 : real_openat)(dirfd, path, flags, mode);
    opened(fd);
    return fd;
}

int __open_2(const char *path, int flags)
{
    int fd;
    pthread_once(&once, init);
    fd = real___open_2 ? real___open_2(path, flags) : real_open(path, flags, 0);
    opened(fd);
    return fd;
}

int __open64_2(const char *path, int flags)
{
    int fd;
    pthread_once(&once, init);
    fd = real___open64_2 ? real___open64_2(path, flags) : real_open(path, flags, 0);
    opened(fd);
    return fd;
}

FILE *fopen(const char *path, const char *mode)
{
    FILE *f;
    pthread_once(&once, init);
    f = real_fopen(path, mode);
    opened_stream(f);
    return f;
}

FILE *fopen64(const char *path, const char *mode)
{
    FILE *f;
    pthread_once(&once, init);
    f = (real_fopen64 ? real_fopen64 : real_fopen)(path, mode);
    opened_stream(f);
    return f;
}

FILE *fdopen(int fd, const char *mode)
{
    FILE *f;
    pthread_once(&once, init);
    f = real_fdopen(fd, mode);
    opened_stream(f);
    return f;
}

FILE *freopen(const char *path, const char *mode, FILE *stream)
{
    FILE *f;
    pthread_once(&once, init);
    f = real_freopen(path, mode, stream);
    opened_stream(f);
    return f;
}

FILE *freopen64(const char *path, const char *mode, FILE *stream)
{
    FILE *f;
    pthread_once(&once, init);
    f = (real_freopen64 ? real_freopen64 : real_freopen)(path, mode, stream);
    opened_stream(f);
    return f;
}

int fclose(FILE *stream)
{
    int fd, rc;
    pthread_once(&once, init);
    fd = stream ? fileno(stream) : -1;
    forget(fd);
    rc = real_fclose(stream);
    forget(fd);
    return rc;
}

/* ------------------------------------------------------------------ port-state requests */

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

/* tcflush semantics on a bench pty; -2: not handled, let the real call do it. Nothing written since the
 * last drain or flush and everything delivered: nothing to flush, nothing to ask. */
static int flush_port(struct bench_port *p, int fd, int queue)
{
    int wrote;
    if (queue != TCOFLUSH && queue != TCIOFLUSH)
        return -2;
    wrote = __atomic_exchange_n(&p->wrote, 0, __ATOMIC_SEQ_CST);
    if ((wrote || !delivered(p)) && ask(p, "flush", NULL, TIMEOUT_S) != 0)
        return -2;
    if (queue == TCIOFLUSH)
        return real_tcflush ? real_tcflush(fd, TCIFLUSH) : real_ioctl(fd, TCFLSH, TCIFLUSH);
    return 0;
}

int ioctl(int fd, unsigned long request, ...)
{
    va_list ap;
    void *arg;
    struct bench_port *p;
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
    case TCFLSH:
        hb_vclock_flushing(fd, (int)(intptr_t)arg);  /* virtual time counts what an input flush drops */
        hb_serve_flush(fd, (int)(intptr_t)arg);
        break;
    case TIOCMGET: case TIOCMSET: case TIOCMBIS: case TIOCMBIC:
    case TIOCSBRK: case TIOCCBRK: case TCSBRK: case TCSBRKP:
    case TCSETS: case TCSETSW: case TCSETSF: case SHIM_TCSETS2: case SHIM_TCSETSW2: case SHIM_TCSETSF2:
    case TCGETS: case SHIM_TCGETS2:
        break;
    case FIONREAD:  /* an empty answer again and again is polling: virtual time may block it a quantum */
        if (serving && arg && hb_serve_inq(fd, (int *)arg)) {
            if (*(int *)arg == 0 && hb_vclock_empty(fd))
                hb_serve_inq(fd, (int *)arg);
            return 0;
        }
        rc = real_ioctl(fd, request, arg);
        if (rc == 0 && arg && *(int *)arg == 0 && hb_vclock_empty(fd))
            rc = real_ioctl(fd, request, arg);
        return rc;
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
        drain_port(p);
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
        drain_port(p);
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
    struct bench_port *p = bench_port(fd);
    hb_vclock_flushing(fd, queue);
    hb_serve_flush(fd, queue);
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
    struct bench_port *p = bench_port(fd);
    if (p)
        drain_port(p);
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
    struct bench_port *p = bench_port(fd);
    int rc;
    if (!real_tcsetattr) {
        errno = ENOSYS;
        return -1;
    }
    if (!p || !t)
        return real_tcsetattr(fd, action, t);
    drain_port(p);
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

/* ------------------------------------------------------------------ the serving path (HILBENCH_SERVE=1) */

/* The bench port behind fd if the bench serves its reads from a ring (or holds ring bytes after a
 * fallback), else NULL. The first use asks the bench to serve it (it checks that every opener runs the
 * shim). */
static struct bench_port *served_port(int fd)
{
    struct bench_port *p;
    uint64_t mode;
    if (!serving || !(p = bench_port(fd)) || !p->ring)
        return NULL;
    if (!__atomic_load_n(&p->claimed, __ATOMIC_ACQUIRE) && !__atomic_load_n(&p->refused, __ATOMIC_ACQUIRE)) {
        int zero = 0;
        long value;
        if (__atomic_compare_exchange_n(&p->claimed, &zero, 1, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST))
            ask(p, "serve", &value, TIMEOUT_S);  /* the answer is in the record's mode */
    }
    mode = __atomic_load_n(&p->ring->mode, __ATOMIC_ACQUIRE);
    if (mode == SERVE_SERVED)
        return p;
    if (mode == SERVE_FALLBACK && __atomic_load_n(&p->ring->head, __ATOMIC_ACQUIRE) !=
                                      __atomic_load_n(&p->ring->tail, __ATOMIC_ACQUIRE))
        return p;  /* bytes served before the fallback come first */
    return NULL;
}

static size_t ring_avail(const struct bench_port *p)
{
    uint64_t tail = __atomic_load_n(&p->ring->tail, __ATOMIC_ACQUIRE);
    return (size_t)(__atomic_load_n(&p->ring->head, __ATOMIC_ACQUIRE) - tail);
}

/* Takes up to n bytes from the ring (several readers: the copy counts only if the tail did not move). */
static size_t ring_take(struct bench_port *p, unsigned char *buf, size_t n)
{
    for (;;) {
        uint64_t tail = __atomic_load_n(&p->ring->tail, __ATOMIC_ACQUIRE);
        uint64_t head = __atomic_load_n(&p->ring->head, __ATOMIC_ACQUIRE);
        size_t k = (size_t)(head - tail), start = (size_t)(tail % SERVE_RING), first;
        if (k > n)
            k = n;
        if (k == 0)
            return 0;
        first = k < SERVE_RING - start ? k : SERVE_RING - start;
        memcpy(buf, p->ring->data + start, first);
        memcpy(buf + first, p->ring->data, k - first);
        if (__atomic_compare_exchange_n(&p->ring->tail, &tail, tail + k, 0, __ATOMIC_SEQ_CST, __ATOMIC_RELAXED))
            return k;
    }
}

static int kernel_inq(int fd)
{
    int n = 0;
    return syscall(SYS_ioctl, fd, FIONREAD, &n) == 0 ? n : 0;
}

/* The wake FIFO's read end (opened once per process and port), or -1. */
static int serve_fifo(struct bench_port *p)
{
    int fd = __atomic_load_n(&p->fifo, __ATOMIC_ACQUIRE);
    if (fd == 0) {
        char path[sizeof sockets[0].path + 16];
        const char *slash = strrchr(sockets[p->sock].path, '/');
        int zero = 0;
        snprintf(path, sizeof path, "%.*s/serve.%d", slash ? (int)(slash - sockets[p->sock].path) : 0,
                 sockets[p->sock].path, p->ring_index);
        fd = real_open ? real_open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC) : -1;
        if (fd == 0) {  /* 0 means "not yet" here: keep another number */
            int other = (int)syscall(SYS_fcntl, fd, F_DUPFD_CLOEXEC, 3);
            close_fd(fd);
            fd = other;
        }
        if (!__atomic_compare_exchange_n(&p->fifo, &zero, fd < 0 ? -1 : fd, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST)) {
            if (fd >= 0)
                close_fd(fd);
            fd = zero;
        }
    }
    return fd;
}

static void drain_fifo(int fd)
{
    char junk[64];
    while (fd >= 0 && syscall(SYS_read, fd, junk, sizeof junk) > 0)
        ;
}

static int64_t mono_ns(void) { return (int64_t)now_ns(); }

/* poll(2) semantics over served descriptors: the kernel's answer for every descriptor (a served pty's
 * own queue, hang-ups), POLLIN where a served pty's ring holds bytes. Blocks on the descriptors and the
 * served ports' wake FIFOs. *handled = 0: no served descriptor (the caller does the real call). */
__attribute__((visibility("hidden"))) int hb_serve_poll(struct pollfd *fds, nfds_t n, int64_t timeout_ns,
                                                        const sigset_t *mask, int *handled)
{
    struct bench_port *served[16];
    int which[16], ns = 0, rc, saved;
    nfds_t i;
    int64_t deadline;
    *handled = 0;
    if (!serving || n > 4096)
        return 0;
    for (i = 0; i < n && ns < 16; i++) {
        struct bench_port *p = (fds[i].events & POLLIN) ? served_port(fds[i].fd) : NULL;
        if (p) {
            served[ns] = p;
            which[ns++] = (int)i;
        }
    }
    if (ns == 0)
        return 0;
    *handled = 1;
    deadline = timeout_ns < 0 ? INT64_MAX : mono_ns() + timeout_ns;
    for (;;) {
        struct timespec zero = {0, 0}, left;
        struct pollfd watch[n + 16 > 4112 ? 1 : n + 16];
        int64_t now;
        int k, ready = 0;
        rc = (int)syscall(SYS_ppoll, fds, n, &zero, mask, 8);
        if (rc < 0)
            return rc;
        for (k = 0; k < ns; k++)
            if (ring_avail(served[k])) {
                if (!fds[which[k]].revents)
                    rc++;
                fds[which[k]].revents |= POLLIN;
                ready = 1;
            }
        now = mono_ns();
        if (rc > 0 || ready || now >= deadline)
            return rc;
        /* block: the descriptors themselves and the FIFOs, counted as waiting, then look again */
        memcpy(watch, fds, n * sizeof *fds);
        for (k = 0; k < ns; k++) {
            watch[n + (nfds_t)k].fd = serve_fifo(served[k]);
            watch[n + (nfds_t)k].events = POLLIN;
            __atomic_add_fetch(&served[k]->ring->waiters, 1, __ATOMIC_SEQ_CST);
        }
        for (k = 0; k < ns && !ready; k++)
            ready = ring_avail(served[k]) != 0;
        if (!ready) {
            int64_t d = deadline - now;
            left.tv_sec = d / 1000000000;
            left.tv_nsec = d % 1000000000;
            rc = (int)syscall(SYS_ppoll, watch, n + (nfds_t)ns, deadline == INT64_MAX ? NULL : &left, mask, 8);
        }
        saved = errno;
        for (k = 0; k < ns; k++) {
            __atomic_sub_fetch(&served[k]->ring->waiters, 1, __ATOMIC_SEQ_CST);
            drain_fifo(watch[n + (nfds_t)k].fd);
        }
        if (!ready && rc < 0) {
            errno = saved;
            return rc;
        }
    }
}

/* select(2) on top of hb_serve_poll; *handled = 0 when no served descriptor is in the read set. */
__attribute__((visibility("hidden"))) int hb_serve_select(int nfds, fd_set *r, fd_set *w, fd_set *e,
                                                          int64_t timeout_ns, const sigset_t *mask, int *handled)
{
    struct pollfd fds[FD_SETSIZE];
    nfds_t k = 0, i;
    int fd, rc, any = 0;
    *handled = 0;
    if (!serving || !r || nfds <= 0 || nfds > FD_SETSIZE)
        return 0;
    for (fd = 0; fd < nfds && !any; fd++)
        any = FD_ISSET(fd, r) && served_port(fd);
    if (!any)
        return 0;
    for (fd = 0; fd < nfds; fd++) {
        short ev = (short)((FD_ISSET(fd, r) ? POLLIN : 0) | (w && FD_ISSET(fd, w) ? POLLOUT : 0) |
                           (e && FD_ISSET(fd, e) ? POLLPRI : 0));
        if (ev) {
            fds[k].fd = fd;
            fds[k].events = ev;
            fds[k++].revents = 0;
        }
    }
    rc = hb_serve_poll(fds, k, timeout_ns, mask, handled);
    if (rc < 0)
        return rc;
    FD_ZERO(r);
    if (w)
        FD_ZERO(w);
    if (e)
        FD_ZERO(e);
    rc = 0;
    for (i = 0; i < k; i++) {
        short got = fds[i].revents;
        if ((fds[i].events & POLLIN) && (got & (POLLIN | POLLHUP | POLLERR))) {
            FD_SET(fds[i].fd, r);
            rc++;
        }
        if (w && (fds[i].events & POLLOUT) && (got & (POLLOUT | POLLERR))) {
            FD_SET(fds[i].fd, w);
            rc++;
        }
        if (e && (fds[i].events & POLLPRI) && (got & POLLPRI)) {
            FD_SET(fds[i].fd, e);
            rc++;
        }
    }
    return rc;
}

/* FIONREAD on a served pty: its own queue plus the ring. 1 if handled. */
__attribute__((visibility("hidden"))) int hb_serve_inq(int fd, int *value)
{
    struct bench_port *p = served_port(fd);
    if (!p)
        return 0;
    *value = kernel_inq(fd) + (int)ring_avail(p);
    return 1;
}

/* An input flush of a served pty drops the ring's unread bytes too. */
static void hb_serve_flush(int fd, int queue)
{
    struct bench_port *p;
    if ((queue != TCIFLUSH && queue != TCIOFLUSH) || !(p = served_port(fd)))
        return;
    for (;;) {
        uint64_t tail = __atomic_load_n(&p->ring->tail, __ATOMIC_ACQUIRE);
        uint64_t head = __atomic_load_n(&p->ring->head, __ATOMIC_ACQUIRE);
        if (__atomic_compare_exchange_n(&p->ring->tail, &tail, head, 0, __ATOMIC_SEQ_CST, __ATOMIC_RELAXED))
            return;
    }
}

/* Up to n bytes of what is there, older first: the pty's own queue (written before the port was served)
 * then the ring; after a fallback the ring's (older) bytes first. */
static ssize_t serve_take(struct bench_port *p, int fd, unsigned char *buf, size_t n)
{
    size_t got = 0;
    int inq = kernel_inq(fd);
    int ring_first = __atomic_load_n(&p->ring->mode, __ATOMIC_ACQUIRE) != SERVE_SERVED;
    if (ring_first)
        got = ring_take(p, buf, n);
    if (got < n && inq > 0) {
        ssize_t r = syscall(SYS_read, fd, buf + got, (size_t)inq < n - got ? (size_t)inq : n - got);
        if (r > 0)
            got += (size_t)r;
    }
    if (!ring_first && got < n)
        got += ring_take(p, buf + got, n - got);
    return (ssize_t)got;
}

/* read(2) of a served pty, raw mode: O_NONBLOCK (EAGAIN when empty), VMIN/VTIME (VMIN counted against
 * both queues, VTIME an inter-byte timer, or the whole wait with VMIN 0). *handled = 0: not served. */
__attribute__((visibility("hidden"))) ssize_t hb_serve_read(int fd, void *buf, size_t n, int *handled)
{
    struct bench_port *p;
    struct termios t;
    size_t want, last = 0;
    int64_t vtime, deadline = INT64_MAX;
    *handled = 0;
    if (!serving || !(p = served_port(fd)))
        return 0;
    *handled = 1;
    if (n == 0)
        return 0;
    if ((int)syscall(SYS_fcntl, fd, F_GETFL) & O_NONBLOCK) {
        ssize_t got = serve_take(p, fd, buf, n);
        if (got == 0) {
            errno = EAGAIN;
            return -1;
        }
        return got;
    }
    if (syscall(SYS_ioctl, fd, TCGETS, &t) != 0)
        return serve_take(p, fd, buf, n);
    vtime = (int64_t)t.c_cc[VTIME] * 100000000;
    want = t.c_cc[VMIN] ? (t.c_cc[VMIN] < n ? t.c_cc[VMIN] : n) : 1;
    if (t.c_cc[VMIN] == 0 && vtime == 0)
        return serve_take(p, fd, buf, n);
    if (t.c_cc[VMIN] == 0)
        deadline = mono_ns() + vtime;
    for (;;) {
        int inq = kernel_inq(fd);
        uint64_t head = __atomic_load_n(&p->ring->head, __ATOMIC_ACQUIRE);
        size_t avail = (size_t)inq + ring_avail(p);
        struct pollfd watch[2];
        struct timespec left;
        int64_t now = mono_ns();
        int k = 0, rc = 0;
        if (avail >= want)
            return serve_take(p, fd, buf, n);
        if (t.c_cc[VMIN] && vtime && avail > last) {  /* the inter-byte timer starts again at each byte */
            last = avail;
            deadline = now + vtime;
        }
        if (now >= deadline)
            return serve_take(p, fd, buf, n);  /* VTIME ran out: what is there (0: none) */
        if (inq == 0) {  /* the pty itself: a hang-up, or a fallback's bytes */
            watch[k].fd = fd;
            watch[k].events = POLLIN;
            watch[k++].revents = 0;
        }
        watch[k].fd = serve_fifo(p);
        watch[k].events = POLLIN;
        watch[k++].revents = 0;
        __atomic_add_fetch(&p->ring->waiters, 1, __ATOMIC_SEQ_CST);
        if (__atomic_load_n(&p->ring->head, __ATOMIC_SEQ_CST) == head) {  /* else: news since we looked */
            int64_t d = deadline - now;
            left.tv_sec = d / 1000000000;
            left.tv_nsec = d % 1000000000;
            rc = (int)syscall(SYS_ppoll, watch, (nfds_t)k, deadline == INT64_MAX ? NULL : &left, NULL, 8);
        }
        __atomic_sub_fetch(&p->ring->waiters, 1, __ATOMIC_SEQ_CST);
        drain_fifo(watch[k - 1].fd);
        if (rc < 0 && errno == EINTR)
            return -1;
        if (inq == 0 && rc > 0 && (watch[0].revents & (POLLHUP | POLLERR)) && !kernel_inq(fd) && !ring_avail(p))
            return serve_take(p, fd, buf, n);  /* nothing will come */
    }
}

__attribute__((visibility("hidden"))) int hb_serve_on(void) { return serving && started(); }

/* For the virtual-time wrappers (vclock.c), which wait in virtual time themselves: the bytes a read of a
 * served pty finds now (its own queue and the ring), -1 when fd is not served. */
__attribute__((visibility("hidden"))) int hb_serve_avail(int fd)
{
    struct bench_port *p = serving ? served_port(fd) : NULL;
    return p ? kernel_inq(fd) + (int)ring_avail(p) : -1;
}

/* ... and up to n of them, without waiting (0: none); -1 when fd is not served. */
__attribute__((visibility("hidden"))) ssize_t hb_serve_take(int fd, void *buf, size_t n)
{
    struct bench_port *p = serving ? served_port(fd) : NULL;
    return p ? serve_take(p, fd, buf, n) : -1;
}

/* fd goes where the ring cannot answer (an epoll set, a stdio stream): the bench stops serving the port,
 * for good (the kernel path from then on), and this process never asks for it. */
__attribute__((visibility("hidden"))) void hb_serve_refuse(int fd)
{
    struct bench_port *p;
    long value;
    int saved = errno;
    if (!serving || !(p = bench_port(fd)) || !p->ring)
        return;
    if (__atomic_exchange_n(&p->refused, 1, __ATOMIC_SEQ_CST) == 0)
        ask(p, "unserve", &value, TIMEOUT_S);
    errno = saved;
}
