/*
 * hilbench run's virtual clock: a client's time, sleeps and timeouts follow a bench's virtual clock.
 *
 * Built with shim.c into one preload library (hilbench/run/build.py). Dormant unless
 * HILBENCH_CLOCK=<dir>/clock.page names the bench's shared page: then every wrapper below
 * passes straight to libc after one predictable branch.
 *
 * The page (hilbench/run/vclock_page.py has the same numbers; PLAN26 §4.2): a header with the
 * virtual time `vnow` (written by the bench's loop only), then one 64-byte slot per client thread,
 * then one record per bench pty. A thread publishes in its slot whether it runs or waits and until
 * when; the loop advances vnow only when every live slot waits, to the earliest deadline (or a
 * bench event), and wakes the threads whose deadline came (a FUTEX_WAKE on the slot's `wake` word,
 * and a byte on the slot's wake FIFO for threads waiting on descriptors).
 *
 * What is virtual: clock_gettime (monotonic family, realtime family), gettimeofday, time; the
 * sleeps (nanosleep, clock_nanosleep incl. TIMER_ABSTIME, usleep, sleep); the timeouts of
 * select, pselect, poll, ppoll, epoll_wait, epoll_pwait, epoll_pwait2; semaphores (sem_wait,
 * sem_timedwait, sem_clockwait: futex_waitv on the semaphore and the slot together); condition
 * variables outside the interpreter (1 ms real slices that re-check the virtual deadline); waiting
 * for children and threads (waitpid, wait4, wait, pthread_join); kill(PID, SIGKILL) returns once PID
 * is dead, so a killed child takes no virtual time to die. The interpreter's own lock (the
 * GIL: pthread_cond_timedwait/wait called from the object that defines PyEval_SaveThread) runs in
 * real time and marks the thread RUNNABLE: its 5 ms drop request is a scheduling heuristic, and a
 * thread waiting for the GIL is not waiting for the world.
 *
 * Not virtual (counted in the header's `unvirtualised`, warned once): alarm, setitimer,
 * timer_settime, timerfd_settime: signals and timer descriptors keep the wall clock.
 *
 * Polling: a thread whose clock reads keep returning the same vnow, or whose 0-timeout polls keep
 * finding nothing, K times in a row (the header's poll_k), counts as waiting: a clock read marks
 * the slot POLLING with deadline vnow + quantum and returns; a 0-timeout poll blocks as a wait
 * with that deadline. Any productive call (a write, data, a blocking wait) resets the count.
 *
 * Threads, processes: pthread_create claims a STARTING slot before the thread exists (the world
 * cannot move in the gap); fork claims the child's slot before the fork; exec and posix_spawn pass
 * the slot to the new image (HILBENCH_CLOCK_SLOT), which adopts it. A thread's slot goes EXITED at
 * its end and a process's at exit; the loop frees EXITED slots and the slots of dead processes.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/futex.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <signal.h>
#include <spawn.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/ioctl.h>
#include <sys/uio.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/select.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/timerfd.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

/* ------------------------------------------------------------------ the page (vclock_page.py) */

#define VC_MAGIC "HBCLOCK1"
#define VC_VERSION 1
#define VC_HEADER 512
#define VC_MAX_SLOTS 4096
#define VC_ENV "HILBENCH_CLOCK"
#define VC_ENV_SLOT "HILBENCH_CLOCK_SLOT"
#define NO_DEADLINE UINT64_MAX
#define NS 1000000000LL
#define TAI_OFFSET (37 * NS)
#define SLICE_NS 1000000LL  /* real slices of waits the loop cannot end directly */

enum { ST_FREE, ST_STARTING, ST_RUNNING, ST_RUNNABLE, ST_WAITING, ST_POLLING, ST_REQUEST, ST_WOKEN, ST_EXITED };
enum { SF_FDWAIT = 1, SF_FOREIGN = 2, SF_INTERP = 4, SF_TIMER = 8, SF_ENDING = 16 };
enum { FLAG_STALL = 1, FLAG_HOLD = 2 };

struct vc_header {
    char magic[8];
    uint32_t version, nslots, nports, reserved0;
    uint64_t vnow, epoch, round, activity;
    uint32_t armed, flags, poll_k, reserved1;
    uint64_t poll_quantum, stalls, origin, stalled_ns, unvirtualised;
    uint32_t nchans, ndoors;      /* socket channels (PLAN26 §4.8 phase 2): see "socket channels" below */
    uint64_t chan_off, chan_timeouts;
};

struct vc_slot {
    uint32_t state, wake, pid, tid;
    uint64_t deadline, ports, act_seen, seen_round;
    uint32_t unproductive, flags;
    uint64_t progress;
};

struct vc_port {
    uint64_t rdev, kind, delivered, read, discarded, written, taken, reserved;
};

/* The bench's socket doors (TCP listeners, UDP sockets whose traffic it counts) and one record per client
 * socket connected or sending to one; counts are bytes (TCP) or datagrams (UDP). */
struct vc_door { uint32_t proto, addr, port, reserved; };
struct vc_chan {
    uint32_t state, pid, proto, addr, port, flags;
    uint64_t sent, received;            /* the client's (atomic adds) */
    uint64_t bench_sent, bench_taken;   /* the bench's totals for this address (the loop stores them) */
    uint64_t given_up;                  /* a bench_sent the client gave up waiting for (CHAN_LIMIT) */
};
enum { CH_FREE, CH_CLAIMING, CH_OPEN };
enum { CF_CONNECTED = 1 };
#define VC_DOOR_SIZE 16
#define VC_MAX_DOORS 32
#define VC_MAX_CHANS 64
_Static_assert(sizeof(struct vc_door) == VC_DOOR_SIZE, "door size");
_Static_assert(sizeof(struct vc_chan) == 64, "channel size");

_Static_assert(sizeof(struct vc_slot) == 64, "slot size");
_Static_assert(sizeof(struct vc_port) == 64, "port size");
_Static_assert(sizeof(struct vc_header) <= VC_HEADER, "header size");
_Static_assert(offsetof(struct vc_header, vnow) == 24 && offsetof(struct vc_header, armed) == 56 &&
               offsetof(struct vc_header, poll_quantum) == 72 && offsetof(struct vc_header, unvirtualised) == 104 &&
               offsetof(struct vc_header, chan_timeouts) == 128, "header layout");

/* The layout as NAME=VALUE lines, for the test that compares it with vclock_page.py. */
const char *hb_vclock_layout(void)
{
    static char buf[4096];
    size_t k;
    snprintf(buf, sizeof buf,
             "VERSION=%d\nHEADER_SIZE=%d\nSLOT_SIZE=%zu\nPORT_SIZE=%zu\n"
             "H_MAGIC=%zu\nH_VERSION=%zu\nH_NSLOTS=%zu\nH_NPORTS=%zu\nH_VNOW=%zu\nH_EPOCH=%zu\nH_ROUND=%zu\nH_ACTIVITY=%zu\n"
             "H_ARMED=%zu\nH_FLAGS=%zu\nH_POLL_K=%zu\nH_POLL_QUANTUM=%zu\nH_STALLS=%zu\nH_ORIGIN=%zu\n"
             "H_STALLED_NS=%zu\nH_UNVIRTUALISED=%zu\n"
             "S_STATE=%zu\nS_WAKE=%zu\nS_PID=%zu\nS_TID=%zu\nS_DEADLINE=%zu\nS_PORTS=%zu\nS_ACT_SEEN=%zu\n"
             "S_SEEN_ROUND=%zu\nS_UNPRODUCTIVE=%zu\nS_FLAGS=%zu\nS_PROGRESS=%zu\n"
             "P_RDEV=%zu\nP_KIND=%zu\nP_DELIVERED=%zu\nP_READ=%zu\nP_DISCARDED=%zu\nP_WRITTEN=%zu\nP_TAKEN=%zu\n"
             "FREE=%d\nSTARTING=%d\nRUNNING=%d\nRUNNABLE=%d\nWAITING=%d\nPOLLING=%d\nREQUEST=%d\nWOKEN=%d\n"
             "EXITED=%d\nSF_FDWAIT=%d\nSF_FOREIGN=%d\nSF_INTERP=%d\nSF_TIMER=%d\nSF_ENDING=%d\nFLAG_STALL=%d\nFLAG_HOLD=%d\n",
             VC_VERSION, VC_HEADER, sizeof(struct vc_slot), sizeof(struct vc_port),
             offsetof(struct vc_header, magic), offsetof(struct vc_header, version), offsetof(struct vc_header, nslots),
             offsetof(struct vc_header, nports), offsetof(struct vc_header, vnow), offsetof(struct vc_header, epoch),
             offsetof(struct vc_header, round), offsetof(struct vc_header, activity),
             offsetof(struct vc_header, armed), offsetof(struct vc_header, flags),
             offsetof(struct vc_header, poll_k), offsetof(struct vc_header, poll_quantum),
             offsetof(struct vc_header, stalls), offsetof(struct vc_header, origin),
             offsetof(struct vc_header, stalled_ns), offsetof(struct vc_header, unvirtualised),
             offsetof(struct vc_slot, state), offsetof(struct vc_slot, wake), offsetof(struct vc_slot, pid),
             offsetof(struct vc_slot, tid), offsetof(struct vc_slot, deadline), offsetof(struct vc_slot, ports),
             offsetof(struct vc_slot, act_seen), offsetof(struct vc_slot, seen_round),
             offsetof(struct vc_slot, unproductive), offsetof(struct vc_slot, flags),
             offsetof(struct vc_slot, progress),
             offsetof(struct vc_port, rdev), offsetof(struct vc_port, kind), offsetof(struct vc_port, delivered),
             offsetof(struct vc_port, read), offsetof(struct vc_port, discarded), offsetof(struct vc_port, written),
             offsetof(struct vc_port, taken),
             ST_FREE, ST_STARTING, ST_RUNNING, ST_RUNNABLE, ST_WAITING, ST_POLLING, ST_REQUEST, ST_WOKEN, ST_EXITED,
             SF_FDWAIT, SF_FOREIGN, SF_INTERP, SF_TIMER, SF_ENDING, FLAG_STALL, FLAG_HOLD);
    k = strlen(buf);
    snprintf(buf + k, sizeof buf - k,
             "H_NCHANS=%zu\nH_NDOORS=%zu\nH_CHAN_OFF=%zu\nH_CHAN_TIMEOUTS=%zu\n"
             "D_PROTO=%zu\nD_ADDR=%zu\nD_PORT=%zu\nDOOR_SIZE=%d\nMAX_DOORS=%d\nCHAN_SIZE=%zu\n"
             "C_STATE=%zu\nC_PID=%zu\nC_PROTO=%zu\nC_ADDR=%zu\nC_PORT=%zu\nC_FLAGS=%zu\nC_SENT=%zu\nC_RECEIVED=%zu\n"
             "C_BENCH_SENT=%zu\nC_BENCH_TAKEN=%zu\nC_GIVEN_UP=%zu\nCH_FREE=%d\nCH_CLAIMING=%d\nCH_OPEN=%d\n"
             "CF_CONNECTED=%d\nTCP=%d\nUDP=%d\n",
             offsetof(struct vc_header, nchans), offsetof(struct vc_header, ndoors),
             offsetof(struct vc_header, chan_off), offsetof(struct vc_header, chan_timeouts),
             offsetof(struct vc_door, proto), offsetof(struct vc_door, addr), offsetof(struct vc_door, port),
             VC_DOOR_SIZE, VC_MAX_DOORS, sizeof(struct vc_chan),
             offsetof(struct vc_chan, state), offsetof(struct vc_chan, pid), offsetof(struct vc_chan, proto),
             offsetof(struct vc_chan, addr), offsetof(struct vc_chan, port), offsetof(struct vc_chan, flags),
             offsetof(struct vc_chan, sent), offsetof(struct vc_chan, received),
             offsetof(struct vc_chan, bench_sent), offsetof(struct vc_chan, bench_taken),
             offsetof(struct vc_chan, given_up), CH_FREE, CH_CLAIMING, CH_OPEN, CF_CONNECTED, IPPROTO_TCP,
             IPPROTO_UDP);
    return buf;
}

/* Atomics for the bench's side (Python through ctypes has none): a compare-and-swap of a state,
 * a wake (bump and FUTEX_WAKE, across processes), an atomic add. */
int hb_vclock_cas32(uint32_t *p, uint32_t expected, uint32_t desired)
{
    return __atomic_compare_exchange_n(p, &expected, desired, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST);
}

void hb_vclock_wake(uint32_t *p)
{
    __atomic_add_fetch(p, 1, __ATOMIC_SEQ_CST);
    syscall(SYS_futex, p, FUTEX_WAKE, INT_MAX, NULL, NULL, 0);
}

uint64_t hb_vclock_add64(uint64_t *p, uint64_t n) { return __atomic_add_fetch(p, n, __ATOMIC_SEQ_CST); }

/* ------------------------------------------------------------------ state */

static struct vc_header *H;
static struct vc_slot *SL;
static struct vc_port *PT;
static struct vc_door *DR;    /* NULL: the page has no socket channels */
static struct vc_chan *CHN;
static uint32_t nchans;
static uint32_t nslots, nports;
static int vc_on;             /* a page is mapped: the wrappers are live */
static pid_t vc_pid;          /* the process the thread-locals below belong to (a vfork child is not it) */
static int notify_fd = -1;
static char clock_dir[PATH_MAX - 32];
static pthread_key_t slot_key;
static int warned_timer;

static __thread struct vc_slot *t_me;   /* this thread's slot */
static __thread int t_off;              /* no slot (none left, or the thread ended): pass through */
static __thread int t_claiming;
static __thread int t_wfd = -1;         /* this slot's wake FIFO, read end */
static __thread uint64_t t_last_v;      /* vnow at the last clock read (polling) */

#define R(name) static __typeof__(name) *r_##name
R(clock_gettime); R(gettimeofday); R(time); R(nanosleep); R(clock_nanosleep); R(usleep); R(sleep);
R(select); R(pselect); R(poll); R(ppoll); R(epoll_wait); R(epoll_pwait);
R(sem_wait); R(sem_timedwait); R(sem_clockwait); R(sem_post);
R(pthread_cond_wait); R(pthread_cond_timedwait); R(pthread_cond_clockwait); R(pthread_cond_signal);
R(pthread_cond_broadcast); R(pthread_create); R(pthread_join); R(fork);
R(execve); R(execvpe); R(fexecve); R(posix_spawn); R(posix_spawnp);
R(waitpid); R(wait4); R(waitid); R(send); R(sendto); R(sendmsg); R(read); R(readv); R(epoll_ctl);
R(alarm); R(setitimer); R(timer_settime); R(timerfd_settime); R(kill);
R(connect); R(recv); R(recvfrom); R(recvmsg); R(recvmmsg); R(sendmmsg);
static int (*r_epoll_pwait2)(int, struct epoll_event *, int, const struct timespec *, const sigset_t *);
static int resolved;

static void resolve(void)
{
#define D(name) r_##name = (__typeof__(r_##name))dlsym(RTLD_NEXT, #name)
    D(clock_gettime); D(gettimeofday); D(time); D(nanosleep); D(clock_nanosleep); D(usleep); D(sleep);
    D(select); D(pselect); D(poll); D(ppoll); D(epoll_wait); D(epoll_pwait); D(epoll_pwait2);
    D(sem_wait); D(sem_timedwait); D(sem_clockwait); D(sem_post);
    D(pthread_cond_wait); D(pthread_cond_timedwait); D(pthread_cond_clockwait); D(pthread_cond_signal);
    D(pthread_cond_broadcast); D(pthread_create); D(pthread_join); D(fork);
    D(execve); D(execvpe); D(fexecve); D(posix_spawn); D(posix_spawnp);
    D(waitpid); D(wait4); D(waitid); D(send); D(sendto); D(sendmsg); D(read); D(readv); D(epoll_ctl);
    D(alarm); D(setitimer); D(timer_settime); D(timerfd_settime); D(kill);
    D(connect); D(recv); D(recvfrom); D(recvmsg); D(recvmmsg); D(sendmmsg);
#undef D
    __atomic_store_n(&resolved, 1, __ATOMIC_RELEASE);
}

#define REAL(name) (__atomic_load_n(&resolved, __ATOMIC_ACQUIRE) ? r_##name : (resolve(), r_##name))

/* The real clock, for the rest of the library (shim.c's delivery ledger stamps stay in real time). */
__attribute__((visibility("hidden"))) int hb_real_clock_gettime(clockid_t clk, struct timespec *tp)
{
    int (*f)(clockid_t, struct timespec *) = REAL(clock_gettime);
    return f ? f(clk, tp) : (int)syscall(SYS_clock_gettime, clk, tp);
}

static int64_t ts_ns(const struct timespec *t) { return (int64_t)t->tv_sec * NS + t->tv_nsec; }
static struct timespec ns_ts(int64_t ns)
{
    struct timespec t;
    if (ns < 0)
        ns = 0;
    t.tv_sec = ns / NS;
    t.tv_nsec = ns % NS;
    return t;
}
static int64_t real_mono(void)
{
    struct timespec t;
    hb_real_clock_gettime(CLOCK_MONOTONIC, &t);
    return ts_ns(&t);
}
static pid_t gettid_(void) { return (pid_t)syscall(SYS_gettid); }

static uint64_t vnow(void) { return __atomic_load_n(&H->vnow, __ATOMIC_ACQUIRE); }
static int64_t rt_offset(void)  /* virtual realtime - virtual monotonic */
{
    return (int64_t)(__atomic_load_n(&H->epoch, __ATOMIC_RELAXED) - __atomic_load_n(&H->origin, __ATOMIC_RELAXED));
}
static uint64_t add_sat(uint64_t a, int64_t b)
{
    if (b < 0)
        return a > (uint64_t)-b ? a + (uint64_t)b : 0;
    return a > NO_DEADLINE - (uint64_t)b ? NO_DEADLINE : a + (uint64_t)b;
}

static int is_mono(clockid_t c)
{
    return c == CLOCK_MONOTONIC || c == CLOCK_MONOTONIC_RAW || c == CLOCK_MONOTONIC_COARSE || c == CLOCK_BOOTTIME ||
           c == CLOCK_BOOTTIME_ALARM;
}
static int is_rt(clockid_t c) { return c == CLOCK_REALTIME || c == CLOCK_REALTIME_COARSE || c == CLOCK_REALTIME_ALARM; }

/* An absolute time on clock `clk` as a virtual monotonic deadline. */
static uint64_t vdeadline(clockid_t clk, const struct timespec *abs)
{
    int64_t t = ts_ns(abs);
    if (clk == CLOCK_TAI)
        t -= TAI_OFFSET;
    if (is_rt(clk) || clk == CLOCK_TAI)
        t -= rt_offset();
    return t < 0 ? 0 : (uint64_t)t;
}

static void nudge(void)
{
    if (notify_fd >= 0 && __atomic_load_n(&H->armed, __ATOMIC_SEQ_CST))
        (void)!syscall(SYS_write, notify_fd, ".", 1);
}

static void bump_activity(void)
{
    if (vc_on)
        __atomic_add_fetch(&H->activity, 1, __ATOMIC_SEQ_CST);
}

/* ------------------------------------------------------------------ slots */

static struct vc_slot *claim(uint32_t state, uint32_t pid, uint32_t tid)
{
    uint32_t i;
    /* A thread that starts another (fork, spawn, a thread) made progress: a /proc look that saw it asleep
     * before (in a call the shim does not wrap) no longer stands for the sleep it may be in now. */
    if (t_me)
        t_me->progress++;
    for (i = 0; i < nslots; i++) {
        uint32_t f = ST_FREE;
        if (__atomic_load_n(&SL[i].state, __ATOMIC_RELAXED) != ST_FREE)
            continue;
        if (__atomic_compare_exchange_n(&SL[i].state, &f, ST_STARTING, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST)) {
            struct vc_slot *s = &SL[i];
            __atomic_store_n(&s->pid, pid, __ATOMIC_SEQ_CST);
            __atomic_store_n(&s->tid, tid, __ATOMIC_SEQ_CST);
            s->deadline = NO_DEADLINE;
            s->ports = 0;
            s->flags = 0;
            s->unproductive = 0;
            s->progress = 0;
            s->act_seen = __atomic_load_n(&H->activity, __ATOMIC_SEQ_CST);
            __atomic_store_n(&s->state, state, __ATOMIC_SEQ_CST);
            nudge();
            return s;
        }
    }
    return NULL;
}

static void release(struct vc_slot *s, uint32_t state)
{
    __atomic_store_n(&s->state, state, __ATOMIC_SEQ_CST);
    bump_activity();  /* an exit is a hand-over: a thread waiting for it is re-checked */
    nudge();
}

/* A claimed slot given back unused (a fork, thread or spawn that failed): no pid is left in it for the
 * loop to judge the next claimer's slot by (it frees a slot whose pid is dead). */
static void unclaim(struct vc_slot *s)
{
    __atomic_store_n(&s->pid, 0, __ATOMIC_SEQ_CST);
    __atomic_store_n(&s->tid, 0, __ATOMIC_SEQ_CST);
    release(s, ST_FREE);
}

/* A slot claimed for a child that is not running yet carries a token in place of a tid (the claimer's tid,
 * high bit set; tids stay below 2^22): the claimer sets the child's pid only while the token is still there.
 * A plain compare-and-swap on pid == 0 could land on a later claim of the same slot when the child had already
 * run, ended and been freed (the claimer preempted meanwhile), giving that claim a dead pid. */
static uint32_t child_token(void) { return 0x80000000u | (uint32_t)gettid_(); }

static void set_child_pid(struct vc_slot *s, uint32_t token, pid_t child)
{
    uint32_t want[2] = {0, token}, set[2] = {(uint32_t)child, token};
    uint64_t expected, desired;
    memcpy(&expected, want, sizeof expected);
    memcpy(&desired, set, sizeof desired);
    __atomic_compare_exchange_n((uint64_t *)(void *)&s->pid, &expected, desired, 0, __ATOMIC_SEQ_CST,
                                __ATOMIC_SEQ_CST);
}

static void close_wake_fd(void)
{
    if (t_wfd >= 0)
        syscall(SYS_close, t_wfd);
    t_wfd = -1;
}

static void thread_gone(void *unused)
{
    (void)unused;
    if (t_me) {
        close_wake_fd();
        release(t_me, ST_EXITED);
    }
    t_me = NULL;
    t_off = 1;
}

/* This thread's slot (claimed on first use for threads the shim did not see start), or NULL. */
static struct vc_slot *cur(void)
{
    struct vc_slot *s;
    if (!vc_on || t_off)
        return NULL;
    if (t_me) {
        t_me->progress++;
        return t_me;
    }
    if (t_claiming)
        return NULL;
    t_claiming = 1;
    s = claim(ST_RUNNING, (uint32_t)vc_pid, (uint32_t)gettid_());
    t_claiming = 0;
    if (!s) {
        t_off = 1;
        return NULL;
    }
    t_me = s;
    pthread_setspecific(slot_key, s);
    return s;
}

static uint32_t slot_index(const struct vc_slot *s) { return (uint32_t)(s - SL); }

/* The read end of this slot's wake FIFO (opened once per thread, emptied of an earlier owner's bytes). */
static int wake_fd(struct vc_slot *s)
{
    char path[PATH_MAX], junk[64];
    if (t_wfd >= 0)
        return t_wfd;
    snprintf(path, sizeof path, "%s/wake.%u", clock_dir, slot_index(s));
    t_wfd = (int)syscall(SYS_openat, AT_FDCWD, path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    while (t_wfd >= 0 && syscall(SYS_read, t_wfd, junk, sizeof junk) > 0)
        ;
    return t_wfd;
}

static void drain_wake_fd(void)
{
    char junk[64];
    while (t_wfd >= 0 && syscall(SYS_read, t_wfd, junk, sizeof junk) > 0)
        ;
}

/* Publish a wait: `act` is the activity read before the caller looked at its condition (a hand-over
 * after that is seen by the loop, which re-checks the slot instead of advancing). */
static uint32_t begin_wait(struct vc_slot *s, uint64_t deadline, uint32_t flags, uint64_t ports, uint64_t act,
                           uint32_t state)
{
    uint32_t w = __atomic_load_n(&s->wake, __ATOMIC_SEQ_CST);
    __atomic_store_n(&s->deadline, deadline, __ATOMIC_RELAXED);
    __atomic_store_n(&s->flags, flags | (s->flags & SF_TIMER), __ATOMIC_RELAXED);
    __atomic_store_n(&s->ports, ports, __ATOMIC_RELAXED);
    __atomic_store_n(&s->act_seen, act, __ATOMIC_RELAXED);
    __atomic_store_n(&s->state, state, __ATOMIC_SEQ_CST);
    nudge();
    return w;
}

static void end_wait(struct vc_slot *s)
{
    __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
    s->unproductive = 0;
    s->seen_round = __atomic_load_n(&H->round, __ATOMIC_RELAXED);
}

static uint64_t activity(void) { return __atomic_load_n(&H->activity, __ATOMIC_SEQ_CST); }

static long futex_wait(uint32_t *addr, uint32_t val, const struct timespec *rel)
{
    return syscall(SYS_futex, addr, FUTEX_WAIT, val, rel, NULL, 0);
}

/* A productive call (data, a write): the thread is not polling. */
static void productive(void)
{
    struct vc_slot *s = vc_on && !t_off ? t_me : NULL;
    uint32_t st;
    if (!s)
        return;
    s->unproductive = 0;
    st = __atomic_load_n(&s->state, __ATOMIC_RELAXED);
    if (st == ST_POLLING || st == ST_WOKEN)  /* it found something: it computes now, and holds the clock */
        __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
}

/* One more call that found nothing; 1 when the thread counts as polling now. */
static int unproductive(struct vc_slot *s)
{
    if (__atomic_load_n(&s->state, __ATOMIC_RELAXED) == ST_POLLING) {
        /* Its clock reads at this instant made it a poller already (the official SDK reads the clock after
         * each empty poll): its next empty poll waits at once, instead of K more calls spinning beside the
         * bench on the machine's CPUs before time can move. */
        s->unproductive = 0;
        return 1;
    }
    if (++s->unproductive < __atomic_load_n(&H->poll_k, __ATOMIC_RELAXED))
        return 0;
    s->unproductive = 0;
    return 1;
}

static uint64_t quantum(void) { return __atomic_load_n(&H->poll_quantum, __ATOMIC_RELAXED); }

/* ------------------------------------------------------------------ set up */

static void adopt_or_claim(void)
{
    const char *env = getenv(VC_ENV_SLOT);
    pid_t pid = getpid();
    struct vc_slot *s = NULL;
    uint32_t i;
    if (env) {
        char *end;
        unsigned long n = strtoul(env, &end, 10);
        if (*end == '\0' && n < nslots && __atomic_load_n(&SL[n].state, __ATOMIC_SEQ_CST) == ST_STARTING) {
            uint32_t expected = 0;
            __atomic_compare_exchange_n(&SL[n].pid, &expected, (uint32_t)pid, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST);
            if (__atomic_load_n(&SL[n].pid, __ATOMIC_SEQ_CST) == (uint32_t)pid)
                s = &SL[n];
        }
        unsetenv(VC_ENV_SLOT);
    }
    /* Slots of threads an exec ended (same pid, not the adopted one): gone. */
    for (i = 0; i < nslots; i++) {
        uint32_t st = __atomic_load_n(&SL[i].state, __ATOMIC_SEQ_CST);
        if (&SL[i] != s && st != ST_FREE && st != ST_EXITED && __atomic_load_n(&SL[i].pid, __ATOMIC_SEQ_CST) ==
                                                                     (uint32_t)pid)
            release(&SL[i], ST_EXITED);
    }
    if (s) {
        __atomic_store_n(&s->tid, (uint32_t)gettid_(), __ATOMIC_SEQ_CST);
        s->deadline = NO_DEADLINE;
        s->flags = 0;
        s->unproductive = 0;
        __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
        nudge();
    } else {
        s = claim(ST_RUNNING, (uint32_t)pid, (uint32_t)gettid_());
    }
    t_me = s;
    t_off = s == NULL;
}

__attribute__((constructor)) static void vclock_init(void)
{
    const char *path = getenv(VC_ENV), *slash;
    struct stat st;
    void *page;
    int fd, saved = errno;
    if (!resolved)
        resolve();
    if (!path || !*path)
        return;
    slash = strrchr(path, '/');
    if (!slash || (size_t)(slash - path) >= sizeof clock_dir)
        return;
    memcpy(clock_dir, path, (size_t)(slash - path));
    clock_dir[slash - path] = '\0';
    fd = (int)syscall(SYS_openat, AT_FDCWD, path, O_RDWR | O_CLOEXEC);
    if (fd < 0)
        goto out;
    if (fstat(fd, &st) != 0 || st.st_size < VC_HEADER) {
        syscall(SYS_close, fd);
        goto out;
    }
    page = mmap(NULL, (size_t)st.st_size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    syscall(SYS_close, fd);
    if (page == MAP_FAILED)
        goto out;
    H = page;
    nslots = H->nslots;
    nports = H->nports;
    if (memcmp(H->magic, VC_MAGIC, 8) != 0 || H->version != VC_VERSION || nslots == 0 || nslots > VC_MAX_SLOTS ||
        nports > 64 || VC_HEADER + 64ull * (nslots + nports) > (uint64_t)st.st_size) {
        munmap(page, (size_t)st.st_size);
        H = NULL;
        goto out;
    }
    SL = (struct vc_slot *)((char *)page + VC_HEADER);
    PT = (struct vc_port *)(SL + nslots);
    if (H->nchans && H->nchans <= VC_MAX_CHANS && H->chan_off >= VC_HEADER + 64ull * (nslots + nports) &&
        H->chan_off + (uint64_t)VC_DOOR_SIZE * VC_MAX_DOORS + 64ull * H->nchans <= (uint64_t)st.st_size) {
        nchans = H->nchans;
        DR = (struct vc_door *)((char *)page + H->chan_off);
        CHN = (struct vc_chan *)(DR + VC_MAX_DOORS);
    }
    {
        char notify[PATH_MAX];
        snprintf(notify, sizeof notify, "%s/clock.notify", clock_dir);
        notify_fd = (int)syscall(SYS_openat, AT_FDCWD, notify, O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    }
    pthread_key_create(&slot_key, thread_gone);
    vc_pid = getpid();
    vc_on = 1;
    adopt_or_claim();
out:
    errno = saved;
}

__attribute__((destructor)) static void vclock_fini(void)
{
    uint32_t i;
    if (!vc_on || getpid() != vc_pid)
        return;
    for (i = 0; i < nslots; i++) {
        uint32_t st = __atomic_load_n(&SL[i].state, __ATOMIC_SEQ_CST);
        if (st != ST_FREE && st != ST_EXITED && __atomic_load_n(&SL[i].pid, __ATOMIC_SEQ_CST) == (uint32_t)vc_pid) {
            /* the process ends (not one thread): the loop holds time until it has ended (a parent waits) */
            __atomic_or_fetch(&SL[i].flags, SF_ENDING, __ATOMIC_SEQ_CST);
            release(&SL[i], ST_EXITED);
        }
    }
    vc_on = 0;
}

/* ------------------------------------------------------------------ clocks */

int clock_gettime(clockid_t clk, struct timespec *tp)
{
    struct vc_slot *s;
    uint64_t v;
    int64_t t;
    if (!vc_on || !(is_mono(clk) || is_rt(clk) || clk == CLOCK_TAI))
        return hb_real_clock_gettime(clk, tp);
    v = vnow();
    s = cur();
    if (s) {
        if (v != t_last_v) {
            t_last_v = v;
            s->unproductive = 0;
            if (__atomic_load_n(&s->state, __ATOMIC_SEQ_CST) != ST_RUNNING)
                __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
        } else if (__atomic_load_n(&s->state, __ATOMIC_RELAXED) == ST_WOKEN) {
            __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
        } else if (__atomic_load_n(&s->state, __ATOMIC_RELAXED) == ST_RUNNING && unproductive(s)) {
            /* Never block in a clock read (Python holds the GIL here): only say "polling". */
            begin_wait(s, add_sat(v, (int64_t)quantum()), 0, 0, activity(), ST_POLLING);
        }
    }
    t = (int64_t)v;
    if (is_rt(clk))
        t += rt_offset();
    else if (clk == CLOCK_TAI)
        t += rt_offset() + TAI_OFFSET;
    *tp = ns_ts(t);
    return 0;
}

int gettimeofday(struct timeval *restrict tv, void *restrict tz)
{
    struct timespec ts;
    if (!vc_on)
        return REAL(gettimeofday)(tv, tz);
    if (tz) {
        struct timeval junk;
        REAL(gettimeofday)(&junk, tz);
    }
    clock_gettime(CLOCK_REALTIME, &ts);
    tv->tv_sec = ts.tv_sec;
    tv->tv_usec = ts.tv_nsec / 1000;
    return 0;
}

time_t time(time_t *out)
{
    struct timespec ts;
    if (!vc_on)
        return REAL(time)(out);
    clock_gettime(CLOCK_REALTIME, &ts);
    if (out)
        *out = ts.tv_sec;
    return ts.tv_sec;
}

/* ------------------------------------------------------------------ sleeps */

/* Wait until vnow reaches `deadline`; 0, or EINTR (a signal). */
static int sleep_until(struct vc_slot *s, uint64_t deadline)
{
    for (;;) {
        uint64_t act = activity();
        uint32_t w;
        long rc;
        if (vnow() >= deadline)
            break;
        w = begin_wait(s, deadline, 0, 0, act, ST_WAITING);
        if (vnow() >= deadline)
            break;
        rc = futex_wait(&s->wake, w, NULL);
        if (rc < 0 && errno == EINTR) {
            end_wait(s);
            return EINTR;
        }
        if (rc < 0 && errno != EAGAIN) {  /* no futex on this mapping: real slices */
            struct timespec slice = ns_ts(SLICE_NS);
            syscall(SYS_nanosleep, &slice, NULL);
        }
    }
    end_wait(s);
    return 0;
}

/* A sleep of `ns` virtual ns (0: a poller's yield). Returns 0 or EINTR; *left: what remains. */
static int vsleep(struct vc_slot *s, int64_t ns, int64_t *left)
{
    uint64_t deadline;
    int rc;
    if (ns <= 0) {
        if (unproductive(s))
            sleep_until(s, add_sat(vnow(), (int64_t)quantum()));
        if (left)
            *left = 0;
        return 0;
    }
    deadline = add_sat(vnow(), ns);
    rc = sleep_until(s, deadline);
    if (left)
        *left = rc ? (int64_t)(deadline - vnow()) : 0;
    return rc;
}

static int bad_ts(const struct timespec *t) { return !t || t->tv_nsec < 0 || t->tv_nsec >= NS || t->tv_sec < 0; }

int nanosleep(const struct timespec *req, struct timespec *rem)
{
    struct vc_slot *s = bad_ts(req) ? NULL : cur();
    int64_t left;
    if (!s)
        return REAL(nanosleep)(req, rem);
    if (vsleep(s, ts_ns(req), &left) == EINTR) {
        if (rem)
            *rem = ns_ts(left);
        errno = EINTR;
        return -1;
    }
    return 0;
}

int clock_nanosleep(clockid_t clk, int flags, const struct timespec *req, struct timespec *rem)
{
    struct vc_slot *s = NULL;
    int64_t left;
    int rc;
    if (vc_on && !bad_ts(req) && (is_mono(clk) || is_rt(clk) || clk == CLOCK_TAI))
        s = cur();
    if (!s)
        return REAL(clock_nanosleep)(clk, flags, req, rem);
    if (flags & TIMER_ABSTIME) {
        uint64_t deadline = vdeadline(clk, req);
        if (deadline <= vnow()) {
            if (unproductive(s))
                sleep_until(s, add_sat(vnow(), (int64_t)quantum()));
            return 0;
        }
        return sleep_until(s, deadline);
    }
    rc = vsleep(s, ts_ns(req), &left);
    if (rc == EINTR && rem)
        *rem = ns_ts(left);
    return rc;
}

int usleep(useconds_t us)
{
    struct vc_slot *s = cur();
    if (!s)
        return REAL(usleep)(us);
    if (vsleep(s, (int64_t)us * 1000, NULL) == EINTR) {
        errno = EINTR;
        return -1;
    }
    return 0;
}

unsigned int sleep(unsigned int seconds)
{
    struct vc_slot *s = cur();
    int64_t left;
    if (!s)
        return REAL(sleep)(seconds);
    if (vsleep(s, (int64_t)seconds * NS, &left) == EINTR)
        return (unsigned int)((left + NS - 1) / NS);
    return 0;
}

/* ------------------------------------------------------------------ waits on descriptors */

/* fd -> 0: not looked up, 1: not a bench port, 2 + i: port record i. shim.c forgets closed fds. */
#define VC_FD_CACHE 65536
static unsigned char vc_fd_port[VC_FD_CACHE];

/* epoll descriptors: the bench ports in their sets (bit 63: something else too). Only grows until the
 * epoll descriptor is closed: a port removed from a set at most costs the slot a spurious wake. */
static uint64_t *ep_ports;

static void chan_forget(int fd);

__attribute__((visibility("hidden"))) void hb_vclock_forget(int fd)
{
    if (fd >= 0 && fd < VC_FD_CACHE) {
        __atomic_store_n(&vc_fd_port[fd], 0, __ATOMIC_RELAXED);
        if (ep_ports)
            __atomic_store_n(&ep_ports[fd], 0, __ATOMIC_RELAXED);
        chan_forget(fd);
    }
}

/* The bench port record behind fd, or -1. */
static int port_of(int fd)
{
    struct stat st;
    unsigned char known;
    int i = -1, saved;
    uint32_t j;
    if (!nports || fd < 0)
        return -1;
    if (fd < VC_FD_CACHE && (known = __atomic_load_n(&vc_fd_port[fd], __ATOMIC_RELAXED)) != 0)
        return known - 2;
    saved = errno;
    if (fstat(fd, &st) == 0 && S_ISCHR(st.st_mode))
        for (j = 0; j < nports; j++)
            if (PT[j].rdev == (uint64_t)st.st_rdev)
                i = (int)j;
    errno = saved;
    if (fd < VC_FD_CACHE)
        __atomic_store_n(&vc_fd_port[fd], (unsigned char)(i + 2), __ATOMIC_RELAXED);
    return i;
}

#define EP_FOREIGN (1ull << 63)

/* ------------------------------------------------------------------ socket channels (PLAN26 §4.8, phase 2)
 *
 * A client socket connected or sending to one of the bench's doors (its socketcand listeners, its UDP
 * endpoints: the page's door table) is a *channel*: it claims a record on the page with its own address,
 * counts what it sends and receives there, and the bench's loop stores beside it what the bench sent to and
 * took from that address. So the loop knows when bytes to the bench are in flight (it does not move time
 * then), and wakes a thread waiting on the channel when the bench sent to it, at the instant of the send (the
 * channel's bit in the slot's `ports`, after the ptys'). A thread about to report "nothing there" on a channel
 * the bench sent to first waits, RUNNABLE (the clock holds), until the bytes show: loopback delivery can
 * finish after the bench's send returned (softirq deferral under load). */

#define CHAN_LIMIT_NS (100 * 1000000LL)  /* real time a thread waits at most for a channel's bytes to show */
static unsigned char vc_fd_chan[VC_FD_CACHE];  /* fd -> 0: not looked up, 1: no channel, 2 + c */
static int chan_fd[VC_MAX_CHANS];              /* channel -> an fd of this process on it (for its queue) */
static uint64_t *ep_chans;                     /* epoll fd -> the channels in its set (with ep_ports) */

static uint32_t chan_bit(uint32_t c) { return nports + c < 62 ? nports + c : 62; }

static int sock_proto(int fd)
{
    int type = 0;
    socklen_t len = sizeof type;
    if (getsockopt(fd, SOL_SOCKET, SO_TYPE, &type, &len) != 0)
        return 0;
    return type == SOCK_STREAM ? IPPROTO_TCP : type == SOCK_DGRAM ? IPPROTO_UDP : 0;
}

/* Whether `sa` is one of the bench's doors for `proto`: 1 + its index, or 0. */
static int is_door(int proto, const struct sockaddr *sa, socklen_t len)
{
    const struct sockaddr_in *in = (const struct sockaddr_in *)sa;
    uint32_t i, n;
    if (!DR || !sa || len < (socklen_t)sizeof *in || in->sin_family != AF_INET)
        return 0;
    n = __atomic_load_n(&H->ndoors, __ATOMIC_ACQUIRE);
    for (i = 0; i < n && i < VC_MAX_DOORS; i++)
        if (DR[i].proto == (uint32_t)proto && DR[i].port == ntohs(in->sin_port) &&
            (DR[i].addr == 0 || DR[i].addr == in->sin_addr.s_addr))
            return (int)i + 1;
    return 0;
}

/* The record of (proto, addr, port); a socket bound to any address (0) matches on its port. */
static int chan_find(uint32_t proto, uint32_t addr, uint32_t port)
{
    uint32_t c;
    for (c = 0; c < nchans; c++)
        if (__atomic_load_n(&CHN[c].state, __ATOMIC_ACQUIRE) == CH_OPEN && CHN[c].proto == proto &&
            (CHN[c].addr == addr || !addr) && CHN[c].port == port)
            return (int)c;
    return -1;
}

static void chan_cache(int fd, int c)
{
    if (fd >= 0 && fd < VC_FD_CACHE)
        __atomic_store_n(&vc_fd_chan[fd], (unsigned char)(c < 0 ? 1 : c + 2), __ATOMIC_RELAXED);
    if (c >= 0)
        chan_fd[c] = fd;
}

/* The channel record of socket fd (found by its own address), or -1. */
static int chan_of(int fd)
{
    struct sockaddr_in in;
    socklen_t len = sizeof in;
    unsigned char known;
    int c = -1, saved, proto;
    if (!CHN || fd < 0 || !__atomic_load_n(&H->ndoors, __ATOMIC_RELAXED))
        return -1;
    if (fd < VC_FD_CACHE && (known = __atomic_load_n(&vc_fd_chan[fd], __ATOMIC_RELAXED)) != 0) {
        if (known >= 2)
            chan_fd[known - 2] = fd;
        return known - 2;
    }
    saved = errno;
    if (getsockname(fd, (struct sockaddr *)&in, &len) == 0 && in.sin_family == AF_INET &&
        (proto = sock_proto(fd)) != 0)
        c = chan_find((uint32_t)proto, in.sin_addr.s_addr, ntohs(in.sin_port));
    errno = saved;
    /* (a socket that is no channel yet may become one: connect and sendto look it up again) */
    if (c >= 0 || fd >= VC_FD_CACHE || len == sizeof in)
        chan_cache(fd, c);
    return c;
}

/* fd has just connected or sent to door `to`: its channel record (claimed now if it has none), or -1. The
 * record holds the address the bench sees the socket's traffic come from: a socket bound to any address
 * sends to a loopback door from the door's address (127.0.0.1 for one bound to any, too). */
static int chan_claim(int fd, int proto, int connected, const struct sockaddr *to)
{
    struct sockaddr_in in;
    socklen_t len = sizeof in;
    uint32_t c;
    int saved = errno, found;
    if (getsockname(fd, (struct sockaddr *)&in, &len) != 0 || in.sin_family != AF_INET || !in.sin_port) {
        errno = saved;
        return -1;
    }
    errno = saved;
    if (!in.sin_addr.s_addr)
        in.sin_addr.s_addr = ((const struct sockaddr_in *)to)->sin_addr.s_addr ?
                             ((const struct sockaddr_in *)to)->sin_addr.s_addr : htonl(INADDR_LOOPBACK);
    found = chan_find((uint32_t)proto, in.sin_addr.s_addr, ntohs(in.sin_port));
    if (found >= 0) {
        if (connected)
            __atomic_or_fetch(&CHN[found].flags, CF_CONNECTED, __ATOMIC_SEQ_CST);
        chan_cache(fd, found);
        return found;
    }
    for (c = 0; c < nchans; c++) {
        uint32_t f = CH_FREE;
        struct vc_chan *r = &CHN[c];
        if (__atomic_load_n(&r->state, __ATOMIC_RELAXED) != CH_FREE ||
            !__atomic_compare_exchange_n(&r->state, &f, CH_CLAIMING, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST))
            continue;
        r->pid = (uint32_t)syscall(SYS_getpid);
        r->proto = (uint32_t)proto;
        r->addr = in.sin_addr.s_addr;
        r->port = ntohs(in.sin_port);
        r->flags = (connected ? CF_CONNECTED : 0) | (uint32_t)is_door(proto, to, sizeof in) << 8;
        r->sent = r->received = r->given_up = 0;
        r->bench_sent = r->bench_taken = 0;
        __atomic_store_n(&r->state, CH_OPEN, __ATOMIC_SEQ_CST);
        chan_cache(fd, (int)c);
        nudge();
        return (int)c;
    }
    return -1;  /* no record left: the socket works as before, without the channel's guarantees */
}

/* fd is closed or replaced: its record goes when its owner closes it (a forked child's close does not). */
static void chan_forget(int fd)
{
    unsigned char known = __atomic_exchange_n(&vc_fd_chan[fd], 0, __ATOMIC_RELAXED);
    if (ep_chans)
        __atomic_store_n(&ep_chans[fd], 0, __ATOMIC_RELAXED);
    if (known >= 2 && CHN) {
        struct vc_chan *r = &CHN[known - 2];
        if (r->pid == (uint32_t)syscall(SYS_getpid) && chan_fd[known - 2] == fd) {
            uint32_t open = CH_OPEN;
            chan_fd[known - 2] = -1;
            if (__atomic_compare_exchange_n(&r->state, &open, CH_CLAIMING, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST)) {
                r->pid = 0;
                __atomic_store_n(&r->state, CH_FREE, __ATOMIC_SEQ_CST);
                bump_activity();
                nudge();
            }
        }
    }
}

static void chan_count(uint64_t *field, uint64_t n)
{
    if (n)
        __atomic_add_fetch(field, n, __ATOMIC_SEQ_CST);
}

/* Whether a channel in `chans` has bytes (datagrams) the bench sent that have not shown in its queue yet. */
static int chan_pending(uint64_t chans)
{
    uint32_t c;
    for (c = 0; chans && c < nchans; c++, chans >>= 1) {
        struct vc_chan *r = &CHN[c];
        uint64_t bs, got;
        int fd, n = 0;
        if (!(chans & 1) || __atomic_load_n(&r->state, __ATOMIC_SEQ_CST) != CH_OPEN)
            continue;
        bs = __atomic_load_n(&r->bench_sent, __ATOMIC_SEQ_CST);
        got = __atomic_load_n(&r->received, __ATOMIC_SEQ_CST);
        if (bs <= got || bs <= __atomic_load_n(&r->given_up, __ATOMIC_RELAXED) || (fd = chan_fd[c]) < 0)
            continue;
        if (r->proto == IPPROTO_TCP) {
            if (syscall(SYS_ioctl, fd, FIONREAD, &n) != 0 || got + (uint64_t)n >= bs)
                continue;
        } else {
            struct pollfd p = {fd, POLLIN, 0};
            if (REAL(poll)(&p, 1, 0) != 0)  /* something is queued (or the socket is gone): it shows */
                continue;
        }
        return 1;
    }
    return 0;
}

static void chan_give_up(uint64_t chans)
{
    uint32_t c;
    for (c = 0; chans && c < nchans; c++, chans >>= 1)
        if (chans & 1)
            __atomic_store_n(&CHN[c].given_up, __atomic_load_n(&CHN[c].bench_sent, __ATOMIC_SEQ_CST),
                             __ATOMIC_SEQ_CST);
    __atomic_add_fetch(&H->chan_timeouts, 1, __ATOMIC_RELAXED);
}

/* Wait (real time, the slot RUNNABLE: the clock holds) until what the bench sent on `chans` shows, at most
 * CHAN_LIMIT_NS; `watch` (n entries) is what the caller waits on, polled in 1 ms slices meanwhile. */
static void chan_settle(struct vc_slot *s, const struct pollfd *watch, nfds_t n, uint64_t chans)
{
    int64_t t0 = real_mono();
    struct pollfd stack[8];
    nfds_t k = n < 8 ? n : 8;
    uint32_t before = __atomic_load_n(&s->state, __ATOMIC_SEQ_CST);
    while (chan_pending(chans)) {
        struct timespec slice = ns_ts(SLICE_NS);
        if (real_mono() - t0 > CHAN_LIMIT_NS) {
            chan_give_up(chans);
            break;
        }
        __atomic_store_n(&s->state, ST_RUNNABLE, __ATOMIC_SEQ_CST);
        memcpy(stack, watch, k * sizeof *stack);
        REAL(ppoll)(stack, k, &slice, NULL);
    }
    __atomic_store_n(&s->state, before == ST_WAITING || before == ST_WOKEN ? ST_RUNNING : before, __ATOMIC_SEQ_CST);
}

/* Which of `fds` are bench ports (a bitmask), and whether any is not (then the wait is foreign); an
 * epoll descriptor stands for its set. Channels waited on for input add their bits, and their records
 * to *chans (a wait for output on them is foreign: the loop does not wake it). */
static uint64_t ports_of(const struct pollfd *fds, nfds_t n, int *foreign, uint64_t *chans)
{
    uint64_t mask = 0;
    nfds_t i;
    for (i = 0; i < n; i++) {
        int fd = fds[i].fd, p;
        uint64_t ep;
        if (fd < 0)
            continue;
        if (ep_ports && fd < VC_FD_CACHE && (ep = __atomic_load_n(&ep_ports[fd], __ATOMIC_RELAXED)) != 0) {
            mask |= ep & ~EP_FOREIGN;
            *foreign |= (ep & EP_FOREIGN) != 0;
            if (ep_chans)
                *chans |= __atomic_load_n(&ep_chans[fd], __ATOMIC_RELAXED);
            continue;
        }
        p = port_of(fd);
        if (p < 0 && (p = chan_of(fd)) >= 0) {
            if (fds[i].events & POLLIN) {
                mask |= 1ull << chan_bit((uint32_t)p);
                *chans |= 1ull << p;
            }
            if (fds[i].events & ~(POLLIN | POLLPRI | POLLRDNORM))
                *foreign = 1;
            continue;
        }
        if (p < 0 || p >= 63)
            *foreign = 1;
        else
            mask |= 1ull << p;
    }
    return mask;
}

/* shim.c: the serving path (HILBENCH_SERVE=1); each sets *handled = 0 for a descriptor it does not serve. */
__attribute__((visibility("hidden"))) int hb_serve_on(void);
__attribute__((visibility("hidden"))) int hb_serve_poll(struct pollfd *fds, nfds_t n, int64_t timeout_ns,
                                                        const sigset_t *mask, int *handled);
__attribute__((visibility("hidden"))) int hb_serve_select(int nfds, fd_set *r, fd_set *w, fd_set *e,
                                                          int64_t timeout_ns, const sigset_t *mask, int *handled);
__attribute__((visibility("hidden"))) ssize_t hb_serve_read(int fd, void *buf, size_t n, int *handled);
__attribute__((visibility("hidden"))) void hb_serve_refuse(int fd);
__attribute__((visibility("hidden"))) int hb_serve_avail(int fd);
__attribute__((visibility("hidden"))) ssize_t hb_serve_take(int fd, void *buf, size_t n);

int epoll_ctl(int ep, int op, int fd, struct epoll_event *ev)
{
    int rc = REAL(epoll_ctl)(ep, op, fd, ev);
    if (rc == 0 && (op == EPOLL_CTL_ADD || op == EPOLL_CTL_MOD) && hb_serve_on())
        hb_serve_refuse(fd);  /* epoll is not served: that pty goes back to the kernel path */
    int c;
    if (rc == 0 && vc_on && (op == EPOLL_CTL_ADD || op == EPOLL_CTL_MOD) && ep >= 0 && ep < VC_FD_CACHE && ev &&
        port_of(fd) < 0 && (c = chan_of(fd)) >= 0) {
        /* a channel in an epoll set: its bit in ep_ports, its record in ep_chans */
        uint64_t bits = ev->events & ~(uint32_t)(EPOLLIN | EPOLLPRI | EPOLLRDNORM | EPOLLET | EPOLLONESHOT |
                                                 EPOLLEXCLUSIVE | EPOLLWAKEUP) ? EP_FOREIGN : 0;
        if (!ep_ports || !ep_chans) {
            uint64_t *t = mmap(NULL, 2 * VC_FD_CACHE * sizeof *t, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                               -1, 0);
            uint64_t *expected = NULL;
            if (t == MAP_FAILED)
                return rc;
            if (!__atomic_compare_exchange_n(&ep_chans, &expected, t + VC_FD_CACHE, 0, __ATOMIC_SEQ_CST,
                                             __ATOMIC_SEQ_CST)) {
                munmap(t, 2 * VC_FD_CACHE * sizeof *t);
                t = NULL;
            }
            expected = NULL;
            if (t)  /* (if ep_ports was set meanwhile, the first half of t stays unused) */
                (void)__atomic_compare_exchange_n(&ep_ports, &expected, t, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST);
        }
        if (ev->events & (EPOLLIN | EPOLLRDNORM)) {
            bits |= 1ull << chan_bit((uint32_t)c);
            __atomic_or_fetch(&ep_chans[ep], 1ull << c, __ATOMIC_RELAXED);
        }
        __atomic_or_fetch(&ep_ports[ep], bits, __ATOMIC_RELAXED);
        return rc;
    }
    if (rc == 0 && vc_on && nports && (op == EPOLL_CTL_ADD || op == EPOLL_CTL_MOD) && ep >= 0 && ep < VC_FD_CACHE) {
        int p = port_of(fd);
        if (!ep_ports) {  /* first use: 512 KiB of address space, touched only where used */
            uint64_t *t = mmap(NULL, VC_FD_CACHE * sizeof *t, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                               -1, 0);
            uint64_t *expected = NULL;
            if (t == MAP_FAILED)
                return rc;
            if (!__atomic_compare_exchange_n(&ep_ports, &expected, t, 0, __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST))
                munmap(t, VC_FD_CACHE * sizeof *t);
        }
        __atomic_or_fetch(&ep_ports[ep], p < 0 || p >= 63 ? EP_FOREIGN : 1ull << p, __ATOMIC_RELAXED);
    }
    return rc;
}

/* One look with a zero timeout (the real call on the caller's own arguments): >0 ready, 0 nothing,
 * -1 an error (errno set). */
typedef int (*probe_fn)(void *ctx);

/* Wait until probe() finds something or vnow reaches `deadline`. `watch` holds what to block on (the
 * caller's descriptors as pollfds) with one spare entry at the end for the wake FIFO. Returns probe()'s
 * result, 0 at the deadline, -1 with EINTR on a signal. */
static int fd_wait(struct vc_slot *s, probe_fn probe, void *ctx, struct pollfd *watch, nfds_t n, uint64_t deadline,
                   const sigset_t *mask)
{
    int foreign = 0;
    uint64_t chans = 0, ports = ports_of(watch, n, &foreign, &chans);
    uint32_t flags = SF_FDWAIT | (foreign ? SF_FOREIGN : 0);
    int wfd = wake_fd(s);
    for (;;) {
        uint64_t act = activity();
        int rc = probe(ctx);
        if (rc != 0)
            goto done_rc;
        if (chans && chan_pending(chans)) {  /* the bench sent: nothing is "not there" until it shows */
            chan_settle(s, watch, n, chans);
            continue;
        }
        if (vnow() >= deadline)
            goto done_rc;
        begin_wait(s, deadline, flags, ports, act, ST_WAITING);
        rc = probe(ctx);
        if (rc != 0 || vnow() >= deadline)
            goto done_rc;
        if (chans && chan_pending(chans))  /* (a send the loop published as this thread began to wait) */
            continue;
        if (wfd >= 0) {
            watch[n].fd = wfd;
            watch[n].events = POLLIN;
            watch[n].revents = 0;
            rc = REAL(ppoll)(watch, n + 1, NULL, mask);
        } else {  /* no wake FIFO: real slices */
            struct timespec slice = ns_ts(SLICE_NS);
            rc = REAL(ppoll)(watch, n, &slice, mask);
        }
        if (rc < 0 && errno == EINTR)
            goto done_rc;
        if (wfd >= 0 && watch[n].revents & POLLNVAL) {  /* the client closed our FIFO (closefrom) */
            t_wfd = -1;
            wfd = wake_fd(s);
        }
        drain_wake_fd();
        continue;
    done_rc:
        end_wait(s);
        return rc;
    }
}

/* How a wrapper with a relative timeout proceeds: `timeout_ns` < 0 is forever. Returns the result. */
static int timed_fd_wait(struct vc_slot *s, probe_fn probe, void *ctx, struct pollfd *watch, nfds_t n,
                         int64_t timeout_ns, const sigset_t *mask, uint64_t *deadline_out)
{
    int rc;
    uint64_t deadline;
    if (timeout_ns == 0) {
        uint64_t chans = 0;
        int foreign = 0;
        rc = probe(ctx);
        if (rc == 0 && CHN && H->ndoors && (ports_of(watch, n, &foreign, &chans), chans) && chan_pending(chans)) {
            chan_settle(s, watch, n, chans);  /* a look at a channel sees what the bench sent before it */
            rc = probe(ctx);
        }
        if (rc != 0) {
            s->unproductive = 0;
            return rc;
        }
        if (!unproductive(s))
            return 0;
        /* A poller: "a poll blocks until the world changes", for one quantum at most. */
        return fd_wait(s, probe, ctx, watch, n, add_sat(vnow(), (int64_t)quantum()), mask);
    }
    deadline = timeout_ns < 0 ? NO_DEADLINE : add_sat(vnow(), timeout_ns);
    if (deadline_out)
        *deadline_out = deadline;
    return fd_wait(s, probe, ctx, watch, n, deadline, mask);
}

/* poll, ppoll */
struct poll_ctx { struct pollfd *fds; nfds_t n; };
static int poll_probe(void *c)
{
    struct poll_ctx *p = c;
    if (hb_serve_on()) {  /* a served pty is readable when its ring holds bytes */
        int handled, rc = hb_serve_poll(p->fds, p->n, 0, NULL, &handled);
        if (handled)
            return rc;
    }
    return REAL(poll)(p->fds, p->n, 0);
}

#define STACK_FDS 64
static int poll_common(struct vc_slot *s, struct pollfd *fds, nfds_t n, int64_t timeout_ns, const sigset_t *mask)
{
    struct poll_ctx ctx = {fds, n};
    struct pollfd stack[STACK_FDS + 1], *watch = stack;
    int rc;
    if (n + 1 > STACK_FDS + 1) {
        watch = malloc((n + 1) * sizeof *watch);
        if (!watch)
            return REAL(ppoll)(fds, n, NULL, mask);
    }
    memcpy(watch, fds, n * sizeof *fds);
    rc = timed_fd_wait(s, poll_probe, &ctx, watch, n, timeout_ns, mask, NULL);
    if (watch != stack)
        free(watch);
    return rc;
}

int poll(struct pollfd *fds, nfds_t n, int timeout)
{
    struct vc_slot *s = cur();
    if (!s && hb_serve_on()) {  /* served ptys (wall clock only, for now) */
        int handled, rc = hb_serve_poll(fds, n, timeout < 0 ? -1 : (int64_t)timeout * 1000000, NULL, &handled);
        if (handled)
            return rc;
    }
    if (!s)
        return REAL(poll)(fds, n, timeout);
    return poll_common(s, fds, n, timeout < 0 ? -1 : (int64_t)timeout * 1000000, NULL);
}

int __poll_chk(struct pollfd *fds, nfds_t n, int timeout, size_t fdslen)
{
    (void)fdslen;
    return poll(fds, n, timeout);
}

int ppoll(struct pollfd *fds, nfds_t n, const struct timespec *ts, const sigset_t *mask)
{
    struct vc_slot *s = ts && bad_ts(ts) ? NULL : cur();
    if (!s && hb_serve_on() && !(ts && bad_ts(ts))) {
        int handled, rc = hb_serve_poll(fds, n, ts ? ts_ns(ts) : -1, mask, &handled);
        if (handled)
            return rc;
    }
    if (!s)
        return REAL(ppoll)(fds, n, ts, mask);
    return poll_common(s, fds, n, ts ? ts_ns(ts) : -1, mask);
}

int __ppoll_chk(struct pollfd *fds, nfds_t n, const struct timespec *ts, const sigset_t *mask, size_t fdslen)
{
    (void)fdslen;
    return ppoll(fds, n, ts, mask);
}

/* select, pselect: the probe works on copies, so the caller's sets hold the last probe's answer. */
struct select_ctx { int n; fd_set *r, *w, *e; fd_set r0, w0, e0; };
static int select_probe(void *c)
{
    struct select_ctx *p = c;
    struct timeval zero = {0, 0};
    if (p->r) *p->r = p->r0;
    if (p->w) *p->w = p->w0;
    if (p->e) *p->e = p->e0;
    if (hb_serve_on()) {
        int handled, rc = hb_serve_select(p->n, p->r, p->w, p->e, 0, NULL, &handled);
        if (handled)
            return rc;
    }
    return REAL(select)(p->n, p->r, p->w, p->e, &zero);
}

static int select_common(struct vc_slot *s, int n, fd_set *r, fd_set *w, fd_set *e, int64_t timeout_ns,
                         const sigset_t *mask, uint64_t *deadline)
{
    struct select_ctx ctx;
    struct pollfd *watch;
    nfds_t k = 0;
    int fd, rc;
    if (n < 0 || n > FD_SETSIZE)
        return -2;
    ctx.n = n; ctx.r = r; ctx.w = w; ctx.e = e;
    if (r) ctx.r0 = *r;
    if (w) ctx.w0 = *w;
    if (e) ctx.e0 = *e;
    watch = malloc(((size_t)n + 1) * sizeof *watch);
    if (!watch)
        return -2;
    for (fd = 0; fd < n; fd++) {
        short ev = (short)((r && FD_ISSET(fd, r) ? POLLIN : 0) | (w && FD_ISSET(fd, w) ? POLLOUT : 0) |
                           (e && FD_ISSET(fd, e) ? POLLPRI : 0));
        if (ev) {
            watch[k].fd = fd;
            watch[k].events = ev;
            k++;
        }
    }
    rc = timed_fd_wait(s, select_probe, &ctx, watch, k, timeout_ns, mask, deadline);
    free(watch);
    if (rc == 0) {  /* a timeout: every set empty, as the kernel leaves them */
        if (r) FD_ZERO(r);
        if (w) FD_ZERO(w);
        if (e) FD_ZERO(e);
    }
    return rc;
}

int select(int n, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv)
{
    struct vc_slot *s = tv && (tv->tv_usec < 0 || tv->tv_usec >= 1000000 || tv->tv_sec < 0) ? NULL : cur();
    uint64_t deadline = NO_DEADLINE;
    int64_t timeout_ns;
    int rc;
    if (!s && hb_serve_on() && !(tv && (tv->tv_usec < 0 || tv->tv_usec >= 1000000 || tv->tv_sec < 0))) {
        int handled;
        rc = hb_serve_select(n, r, w, e, tv ? ((int64_t)tv->tv_sec * 1000000 + tv->tv_usec) * 1000 : -1, NULL,
                             &handled);
        if (handled)
            return rc;  /* (the time left is not written back: served selects are a prototype) */
    }
    if (!s)
        return REAL(select)(n, r, w, e, tv);
    timeout_ns = tv ? ((int64_t)tv->tv_sec * 1000000 + tv->tv_usec) * 1000 : -1;
    rc = select_common(s, n, r, w, e, timeout_ns, NULL, &deadline);
    if (rc == -2)
        return REAL(select)(n, r, w, e, tv);
    if (tv && timeout_ns > 0) {  /* Linux writes back what is left of the timeout */
        uint64_t v = vnow();
        int64_t left = rc > 0 && deadline > v ? (int64_t)(deadline - v) : 0;
        tv->tv_sec = left / NS;
        tv->tv_usec = (left % NS) / 1000;
    }
    return rc;
}

int pselect(int n, fd_set *r, fd_set *w, fd_set *e, const struct timespec *ts, const sigset_t *mask)
{
    struct vc_slot *s = ts && bad_ts(ts) ? NULL : cur();
    int rc;
    if (!s && hb_serve_on() && !(ts && bad_ts(ts))) {
        int handled;
        rc = hb_serve_select(n, r, w, e, ts ? ts_ns(ts) : -1, mask, &handled);
        if (handled)
            return rc;
    }
    if (!s)
        return REAL(pselect)(n, r, w, e, ts, mask);
    rc = select_common(s, n, r, w, e, ts ? ts_ns(ts) : -1, mask, NULL);
    return rc == -2 ? REAL(pselect)(n, r, w, e, ts, mask) : rc;
}

/* epoll: blocks on the epoll descriptor itself (readable when any of its set is ready). */
struct epoll_ctx { int ep, max; struct epoll_event *ev; };
static int epoll_probe(void *c)
{
    struct epoll_ctx *p = c;
    return REAL(epoll_wait)(p->ep, p->ev, p->max, 0);
}

static int epoll_common(struct vc_slot *s, int ep, struct epoll_event *ev, int max, int64_t timeout_ns,
                        const sigset_t *mask)
{
    struct epoll_ctx ctx = {ep, max, ev};
    struct pollfd watch[2] = {{ep, POLLIN, 0}, {-1, 0, 0}};
    if (max <= 0 || !ev) {
        errno = EINVAL;
        return -1;
    }
    return timed_fd_wait(s, epoll_probe, &ctx, watch, 1, timeout_ns, mask, NULL);
}

int epoll_wait(int ep, struct epoll_event *ev, int max, int timeout)
{
    struct vc_slot *s = cur();
    if (!s)
        return REAL(epoll_wait)(ep, ev, max, timeout);
    return epoll_common(s, ep, ev, max, timeout < 0 ? -1 : (int64_t)timeout * 1000000, NULL);
}

int epoll_pwait(int ep, struct epoll_event *ev, int max, int timeout, const sigset_t *mask)
{
    struct vc_slot *s = cur();
    if (!s)
        return REAL(epoll_pwait)(ep, ev, max, timeout, mask);
    return epoll_common(s, ep, ev, max, timeout < 0 ? -1 : (int64_t)timeout * 1000000, mask);
}

int epoll_pwait2(int ep, struct epoll_event *ev, int max, const struct timespec *ts, const sigset_t *mask)
{
    struct vc_slot *s = ts && bad_ts(ts) ? NULL : cur();
    if (!s) {
        if (!REAL(epoll_pwait2)) {
            errno = ENOSYS;
            return -1;
        }
        return r_epoll_pwait2(ep, ev, max, ts, mask);
    }
    return epoll_common(s, ep, ev, max, ts ? ts_ns(ts) : -1, mask);
}

/* ------------------------------------------------------------------ semaphores (futex_waitv) */

#ifndef SYS_futex_waitv
#define SYS_futex_waitv 449
#endif
#ifndef FUTEX2_SIZE_U32
#define FUTEX2_SIZE_U32 0x02
#endif
#ifndef FUTEX2_PRIVATE
#define FUTEX2_PRIVATE 128
#endif
struct vc_futex_waitv { uint64_t val, uaddr; uint32_t flags, reserved; };

/* glibc >= 2.21 with 64-bit atomics: the value in the low word (the futex), waiters above. */
struct new_sem { uint64_t data; int private_; int pad; };
#define SEM_VALUE_MASK 0xffffffffull
#define SEM_NWAITERS_SHIFT 32
static int no_waitv;

/* sem_wait with a virtual deadline: the semaphore's futex and the slot's wake word at once, so a
 * post (another thread) and the loop (another process) both end it. 0, or -1 with errno. */
static int vsem_wait(struct vc_slot *s, sem_t *sem_, uint64_t deadline)
{
    struct new_sem *sem = (struct new_sem *)sem_;
    int rc = 0;
    __atomic_add_fetch(&sem->data, 1ull << SEM_NWAITERS_SHIFT, __ATOMIC_RELAXED);
    for (;;) {
        uint64_t act = activity(), d = __atomic_load_n(&sem->data, __ATOMIC_RELAXED);
        uint32_t w;
        long r;
        if (d & SEM_VALUE_MASK) {
            if (__atomic_compare_exchange_n(&sem->data, &d, d - 1 - (1ull << SEM_NWAITERS_SHIFT), 1,
                                            __ATOMIC_ACQUIRE, __ATOMIC_RELAXED)) {
                end_wait(s);
                return 0;
            }
            continue;
        }
        if (vnow() >= deadline) {
            errno = ETIMEDOUT;
            rc = -1;
            break;
        }
        w = begin_wait(s, deadline, SF_FOREIGN, 0, act, ST_WAITING);
        if (__atomic_load_n(&sem->data, __ATOMIC_SEQ_CST) & SEM_VALUE_MASK || vnow() >= deadline)
            continue;
        if (!no_waitv) {
            /* glibc's `private` is 0 for a process-private semaphore (LLL_PRIVATE is 0). */
            struct vc_futex_waitv v[2] = {
                {0, (uint64_t)(uintptr_t)&sem->data, FUTEX2_SIZE_U32 | (sem->private_ == 0 ? FUTEX2_PRIVATE : 0), 0},
                {w, (uint64_t)(uintptr_t)&s->wake, FUTEX2_SIZE_U32, 0},
            };
            r = syscall(SYS_futex_waitv, v, 2, 0, NULL, 0);
            if (r < 0 && errno == ENOSYS)
                no_waitv = 1;
        } else {  /* no futex_waitv (Linux < 5.16): the semaphore in real slices */
            struct timespec slice = ns_ts(SLICE_NS);
            r = futex_wait((uint32_t *)&sem->data, 0, &slice);
            if (r < 0 && errno == ETIMEDOUT)
                r = 0;
        }
        if (r < 0 && errno == EINTR) {
            rc = -1;
            break;
        }
    }
    __atomic_sub_fetch(&sem->data, 1ull << SEM_NWAITERS_SHIFT, __ATOMIC_RELAXED);
    end_wait(s);
    return rc;
}

int sem_wait(sem_t *sem)
{
    struct vc_slot *s = cur();
    if (!s)
        return REAL(sem_wait)(sem);
    return vsem_wait(s, sem, NO_DEADLINE);
}

int sem_timedwait(sem_t *sem, const struct timespec *abs)
{
    struct vc_slot *s = bad_ts(abs) ? NULL : cur();
    if (!s)
        return REAL(sem_timedwait)(sem, abs);
    return vsem_wait(s, sem, vdeadline(CLOCK_REALTIME, abs));
}

int sem_clockwait(sem_t *sem, clockid_t clk, const struct timespec *abs)
{
    struct vc_slot *s = bad_ts(abs) || !(is_mono(clk) || is_rt(clk)) ? NULL : cur();
    if (!s) {
        if (!REAL(sem_clockwait)) {
            errno = ENOSYS;
            return -1;
        }
        return r_sem_clockwait(sem, clk, abs);
    }
    return vsem_wait(s, sem, vdeadline(clk, abs));
}

int sem_post(sem_t *sem)
{
    if (vc_on) {
        struct new_sem *p = (struct new_sem *)sem;
        productive();
        if (__atomic_load_n(&p->data, __ATOMIC_RELAXED) >> SEM_NWAITERS_SHIFT)
            bump_activity();
    }
    return REAL(sem_post)(sem);
}

/* ------------------------------------------------------------------ condition variables, the GIL rule */

/* Whether the caller lies in the interpreter's object (libpython, or a static python): found by the
 * object that defines PyEval_SaveThread, so the file name does not matter. Cached per call site. */
#define SITES 16
static void *site_addr[SITES];
static unsigned char site_interp[SITES];
static void *py_base = (void *)-1;

static int from_interpreter(void *ret)
{
    Dl_info info;
    int i, in;
    for (i = 0; i < SITES; i++) {
        void *a = __atomic_load_n(&site_addr[i], __ATOMIC_ACQUIRE);
        if (a == ret)
            return site_interp[i];
        if (!a)
            break;
    }
    if (py_base == (void *)-1) {
        void *sym = dlsym(RTLD_DEFAULT, "PyEval_SaveThread");
        Dl_info pi;
        py_base = sym && dladdr(sym, &pi) ? pi.dli_fbase : NULL;
    }
    in = py_base && dladdr(ret, &info) && info.dli_fbase == py_base;
    if (i < SITES) {
        void *expected = NULL;
        site_interp[i] = (unsigned char)in;
        __atomic_compare_exchange_n(&site_addr[i], &expected, ret, 0, __ATOMIC_RELEASE, __ATOMIC_RELAXED);
    }
    return in;
}

/* glibc >= 2.25 (nptl/pthread_cond_common.c): bit 1 of __wrefs is the clock (set: CLOCK_MONOTONIC),
 * bit 0 process-shared, bit 2 a wake request, the waiters' references from bit 3 up. */
static clockid_t cond_clock(pthread_cond_t *c)
{
    return __atomic_load_n(&c->__data.__wrefs, __ATOMIC_RELAXED) & 2 ? CLOCK_MONOTONIC : CLOCK_REALTIME;
}

/* The GIL: a real wait (the virtual deadline converted), the thread RUNNABLE meanwhile. */
static int gil_wait(struct vc_slot *s, pthread_cond_t *c, pthread_mutex_t *m, clockid_t clk,
                    const struct timespec *abs)
{
    uint32_t before = __atomic_load_n(&s->state, __ATOMIC_RELAXED);
    int rc;
    __atomic_or_fetch(&s->flags, SF_INTERP, __ATOMIC_RELAXED);
    if (before == ST_RUNNING)
        __atomic_store_n(&s->state, ST_RUNNABLE, __ATOMIC_SEQ_CST);
    if (abs) {
        int64_t left = (int64_t)(vdeadline(clk, abs) - vnow());
        struct timespec real = ns_ts(real_mono() + (left > 0 ? left : 0));
        rc = REAL(pthread_cond_clockwait)(c, m, CLOCK_MONOTONIC, &real);
    } else {
        rc = REAL(pthread_cond_wait)(c, m);
    }
    __atomic_and_fetch(&s->flags, ~(uint32_t)SF_INTERP, __ATOMIC_RELAXED);
    if (before == ST_RUNNING)
        __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
    return rc;
}

/* A client's condition variable: real waits in 1 ms slices, the slot WAITING with the virtual
 * deadline; the loop's wake (the deadline came, or a hand-over to re-check) ends it as a spurious
 * wake-up, which POSIX allows (ETIMEDOUT only once vnow reaches the deadline). */
static int vcond_wait(struct vc_slot *s, pthread_cond_t *c, pthread_mutex_t *m, uint64_t deadline)
{
    int rc;
    for (;;) {
        uint64_t act = activity();
        uint32_t w;
        struct timespec slice;
        if (vnow() >= deadline) {
            rc = ETIMEDOUT;
            break;
        }
        w = begin_wait(s, deadline, SF_FOREIGN, 0, act, ST_WAITING);
        slice = ns_ts(real_mono() + SLICE_NS);
        rc = REAL(pthread_cond_clockwait)(c, m, CLOCK_MONOTONIC, &slice);
        if (rc != ETIMEDOUT)
            break;
        if (__atomic_load_n(&s->wake, __ATOMIC_SEQ_CST) != w) {
            rc = vnow() >= deadline ? ETIMEDOUT : 0;
            break;
        }
    }
    end_wait(s);
    return rc;
}

int pthread_cond_timedwait(pthread_cond_t *restrict c, pthread_mutex_t *restrict m,
                           const struct timespec *restrict abs)
{
    struct vc_slot *s = bad_ts(abs) ? NULL : cur();
    if (!s)
        return REAL(pthread_cond_timedwait)(c, m, abs);
    if (from_interpreter(__builtin_return_address(0)))
        return gil_wait(s, c, m, cond_clock(c), abs);
    return vcond_wait(s, c, m, vdeadline(cond_clock(c), abs));
}

int pthread_cond_clockwait(pthread_cond_t *restrict c, pthread_mutex_t *restrict m, clockid_t clk,
                           const struct timespec *restrict abs)
{
    struct vc_slot *s = bad_ts(abs) || !(is_mono(clk) || is_rt(clk)) ? NULL : cur();
    if (!s)
        return REAL(pthread_cond_clockwait)(c, m, clk, abs);
    if (from_interpreter(__builtin_return_address(0)))
        return gil_wait(s, c, m, clk, abs);
    return vcond_wait(s, c, m, vdeadline(clk, abs));
}

int pthread_cond_wait(pthread_cond_t *restrict c, pthread_mutex_t *restrict m)
{
    struct vc_slot *s = cur();
    if (!s)
        return REAL(pthread_cond_wait)(c, m);
    if (from_interpreter(__builtin_return_address(0)))
        return gil_wait(s, c, m, CLOCK_MONOTONIC, NULL);
    return vcond_wait(s, c, m, NO_DEADLINE);
}

static void cond_signalled(pthread_cond_t *c)
{
    if (vc_on && __atomic_load_n(&c->__data.__wrefs, __ATOMIC_RELAXED) >> 3)  /* someone waits */
        bump_activity();
}

int pthread_cond_signal(pthread_cond_t *c)
{
    cond_signalled(c);
    return REAL(pthread_cond_signal)(c);
}

int pthread_cond_broadcast(pthread_cond_t *c)
{
    cond_signalled(c);
    return REAL(pthread_cond_broadcast)(c);
}

/* ------------------------------------------------------------------ children and threads to end */

/* Wait in 1 ms real slices on the slot's wake word for `done` to succeed; the slot WAITING without
 * a deadline (a child's or thread's end bumps activity: the loop re-checks this slot first). */
static void wait_slices(struct vc_slot *s, int (*done)(void *), void *ctx, int *interrupted)
{
    *interrupted = 0;
    for (;;) {
        uint64_t act = activity();
        uint32_t w;
        struct timespec slice = ns_ts(SLICE_NS);
        if (done(ctx))
            break;
        w = begin_wait(s, NO_DEADLINE, SF_FOREIGN, 0, act, ST_WAITING);
        if (done(ctx))
            break;
        if (futex_wait(&s->wake, w, &slice) < 0 && errno == EINTR) {
            *interrupted = 1;
            break;
        }
    }
    end_wait(s);
}

struct wait_ctx { pid_t pid; int *status, options; struct rusage *ru; pid_t rc; int err; };
static int wait_done(void *c)
{
    struct wait_ctx *p = c;
    p->rc = REAL(wait4)(p->pid, p->status, p->options | WNOHANG, p->ru);
    p->err = errno;
    return p->rc != 0;
}

static pid_t vwait4(pid_t pid, int *status, int options, struct rusage *ru)
{
    struct vc_slot *s = options & WNOHANG ? NULL : cur();
    struct wait_ctx ctx = {pid, status, options, ru, 0, 0};
    int intr;
    if (!s)
        return REAL(wait4)(pid, status, options, ru);
    wait_slices(s, wait_done, &ctx, &intr);
    if (intr) {
        errno = EINTR;
        return -1;
    }
    errno = ctx.err;
    return ctx.rc;
}

pid_t waitpid(pid_t pid, int *status, int options) { return vwait4(pid, status, options, NULL); }
pid_t wait4(pid_t pid, int *status, int options, struct rusage *ru) { return vwait4(pid, status, options, ru); }
pid_t wait(int *status) { return vwait4(-1, status, 0, NULL); }
pid_t wait3(int *status, int options, struct rusage *ru) { return vwait4(-1, status, options, ru); }

struct waitid_ctx { idtype_t type; id_t id; siginfo_t *info; int options, rc, err; };
static int waitid_done(void *c)
{
    struct waitid_ctx *p = c;
    p->info->si_pid = 0;
    p->rc = REAL(waitid)(p->type, p->id, p->info, p->options | WNOHANG);
    p->err = errno;
    return p->rc != 0 || p->info->si_pid != 0;
}

int waitid(idtype_t type, id_t id, siginfo_t *info, int options)
{
    struct vc_slot *s = options & WNOHANG || !info ? NULL : cur();
    struct waitid_ctx ctx = {type, id, info, options, 0, 0};
    int intr;
    if (!s)
        return REAL(waitid)(type, id, info, options);
    wait_slices(s, waitid_done, &ctx, &intr);
    if (intr) {
        errno = EINTR;
        return -1;
    }
    errno = ctx.err;
    return ctx.rc;
}

struct join_ctx { pthread_t t; void **ret; int rc; };
static int join_done(void *c)
{
    struct join_ctx *p = c;
    p->rc = pthread_tryjoin_np(p->t, p->ret);
    return p->rc != EBUSY;
}

int pthread_join(pthread_t t, void **ret)
{
    struct vc_slot *s = cur();
    struct join_ctx ctx = {t, ret, 0};
    int intr;
    if (!s)
        return REAL(pthread_join)(t, ret);
    do
        wait_slices(s, join_done, &ctx, &intr);
    while (intr);  /* pthread_join never fails with EINTR */
    return ctx.rc;
}

/* kill(PID, SIGKILL) returns once PID has died (at most KILL_WAIT_MS real): the sender's slot is RUNNABLE
 * meanwhile (not RUNNING: the loop would take a thread asleep in the kernel for one waiting where the shim
 * cannot see), so the world cannot move while the victim dies. Without this, a parent that kills a child
 * and reaps it (subprocess's timeout: kill, then waitpid) waited with the dying child's slot still WAITING
 * until the loop saw its pidfd, and the bench's events ran for those real milliseconds (5 to 500 virtual
 * ms). Other signals may be caught: they stay asynchronous. */
#define KILL_WAIT_MS 2000
int kill(pid_t pid, int sig)
{
    struct vc_slot *s = NULL;
    int pfd = -1, rc, err;
    if (vc_on && sig == SIGKILL && pid > 0 && pid != vc_pid && (s = cur()) != NULL)
        pfd = (int)syscall(SYS_pidfd_open, pid, 0);
    rc = REAL(kill)(pid, sig);
    err = errno;
    if (pfd >= 0) {
        struct pollfd p = {pfd, POLLIN, 0};
        uint32_t before = __atomic_load_n(&s->state, __ATOMIC_RELAXED);
        if (before == ST_RUNNING)
            __atomic_store_n(&s->state, ST_RUNNABLE, __ATOMIC_SEQ_CST);
        if (rc == 0)
            while (REAL(poll)(&p, 1, KILL_WAIT_MS) < 0 && errno == EINTR)
                ;
        if (before == ST_RUNNING)
            __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
        syscall(SYS_close, pfd);
    }
    errno = err;
    return rc;
}

/* ------------------------------------------------------------------ threads, fork, exec */

struct trampoline { void *(*fn)(void *); void *arg; struct vc_slot *slot; };

static void *thread_main(void *p)
{
    struct trampoline t = *(struct trampoline *)p;
    void *ret;
    free(p);
    t_me = t.slot;
    t_off = 0;
    t_wfd = -1;
    __atomic_store_n(&t.slot->tid, (uint32_t)gettid_(), __ATOMIC_SEQ_CST);
    __atomic_store_n(&t.slot->state, ST_RUNNING, __ATOMIC_SEQ_CST);
    pthread_setspecific(slot_key, t.slot);
    ret = t.fn(t.arg);
    thread_gone(NULL);
    return ret;
}

int pthread_create(pthread_t *restrict th, const pthread_attr_t *restrict attr, void *(*fn)(void *),
                   void *restrict arg)
{
    struct trampoline *t;
    int rc;
    if (!vc_on)
        return REAL(pthread_create)(th, attr, fn, arg);
    t = malloc(sizeof *t);
    if (!t)
        return REAL(pthread_create)(th, attr, fn, arg);
    /* The slot exists (STARTING: not waiting) before the thread does: the world cannot move in between. */
    t->fn = fn;
    t->arg = arg;
    t->slot = claim(ST_STARTING, (uint32_t)vc_pid, 0);
    if (!t->slot) {
        free(t);
        return REAL(pthread_create)(th, attr, fn, arg);
    }
    productive();
    rc = REAL(pthread_create)(th, attr, thread_main, t);
    if (rc != 0) {
        unclaim(t->slot);
        free(t);
    }
    return rc;
}

pid_t fork(void)
{
    struct vc_slot *child;
    uint32_t token;
    pid_t pid;
    if (!vc_on)
        return REAL(fork)();
    token = child_token();
    child = claim(ST_STARTING, 0, token);  /* the child's slot, before the child runs */
    pid = REAL(fork)();
    if (pid == 0) {
        vc_pid = getpid();
        close_wake_fd();  /* our copy of the parent's slot's FIFO */
        t_me = child;
        t_off = child == NULL;
        if (child) {
            __atomic_store_n(&child->pid, (uint32_t)vc_pid, __ATOMIC_SEQ_CST);
            __atomic_store_n(&child->tid, (uint32_t)gettid_(), __ATOMIC_SEQ_CST);
            __atomic_store_n(&child->state, ST_RUNNING, __ATOMIC_SEQ_CST);
            pthread_setspecific(slot_key, child);
        }
    } else if (child) {
        if (pid < 0) {
            unclaim(child);
        } else {
            set_child_pid(child, token, pid);
        }
    }
    return pid;
}

/* Before an exec: the slot the new image adopts (this thread's, or a new one in a vfork child or an
 * unregistered thread), STARTING meanwhile; `var` gets HILBENCH_CLOCK_SLOT=N. NULL: not under a clock. */
static struct vc_slot *exec_slot(char var[32], uint32_t *old_state)
{
    pid_t pid = (pid_t)syscall(SYS_getpid);
    struct vc_slot *s;
    if (!vc_on)
        return NULL;
    if (pid == vc_pid && t_me && !t_off) {
        s = t_me;
        *old_state = __atomic_exchange_n(&s->state, ST_STARTING, __ATOMIC_SEQ_CST);
    } else {  /* a vfork child shares our memory: touch nothing but the page */
        s = claim(ST_STARTING, (uint32_t)pid, 0);
        *old_state = ST_FREE;
    }
    if (s)
        snprintf(var, 32, "%s=%u", VC_ENV_SLOT, slot_index(s));
    return s;
}

static void exec_failed(struct vc_slot *s, uint32_t old_state)
{
    int saved = errno;
    if (s && old_state == ST_FREE) {  /* (a claim of its own: given back as it was taken, pid and tid first) */
        __atomic_store_n(&s->pid, 0, __ATOMIC_SEQ_CST);
        __atomic_store_n(&s->tid, 0, __ATOMIC_SEQ_CST);
        __atomic_store_n(&s->state, ST_FREE, __ATOMIC_SEQ_CST);
    } else if (s) {
        __atomic_store_n(&s->state, ST_RUNNING, __ATOMIC_SEQ_CST);
    }
    errno = saved;
}

/* envp with our variable instead of any HILBENCH_CLOCK_SLOT in it; `out` has room for n + 2. */
static char **with_slot(char *const envp[], char *var, char **out)
{
    size_t i = 0, k = 0;
    for (; envp && envp[i]; i++)
        if (strncmp(envp[i], VC_ENV_SLOT "=", sizeof VC_ENV_SLOT) != 0)
            out[k++] = envp[i];
    out[k++] = var;
    out[k] = NULL;
    return out;
}

static size_t env_count(char *const envp[])
{
    size_t n = 0;
    while (envp && envp[n])
        n++;
    return n;
}

int execve(const char *path, char *const argv[], char *const envp[])
{
    char var[32];
    uint32_t old;
    struct vc_slot *s = exec_slot(var, &old);
    if (!s)
        return REAL(execve)(path, argv, envp);
    {
        char *env[env_count(envp) + 2];
        REAL(execve)(path, argv, with_slot(envp, var, env));
    }
    exec_failed(s, old);
    return -1;
}

int execv(const char *path, char *const argv[]) { return execve(path, argv, environ); }

int execvpe(const char *file, char *const argv[], char *const envp[])
{
    char var[32];
    uint32_t old;
    struct vc_slot *s = exec_slot(var, &old);
    if (!s)
        return REAL(execvpe)(file, argv, envp);
    {
        char *env[env_count(envp) + 2];
        REAL(execvpe)(file, argv, with_slot(envp, var, env));
    }
    exec_failed(s, old);
    return -1;
}

int execvp(const char *file, char *const argv[]) { return execvpe(file, argv, environ); }

int fexecve(int fd, char *const argv[], char *const envp[])
{
    char var[32];
    uint32_t old;
    struct vc_slot *s = exec_slot(var, &old);
    if (!s)
        return REAL(fexecve)(fd, argv, envp);
    {
        char *env[env_count(envp) + 2];
        REAL(fexecve)(fd, argv, with_slot(envp, var, env));
    }
    exec_failed(s, old);
    return -1;
}

#define EXECL_ARGV(first, ap, argv)                          \
    do {                                                               \
        size_t n_ = 1;                                                 \
        va_list c_;                                                    \
        va_copy(c_, ap);                                               \
        while (va_arg(c_, char *))                                     \
            n_++;                                                      \
        va_end(c_);                                                    \
        argv = alloca((n_ + 1) * sizeof(char *));                      \
        argv[0] = (char *)(first);                                     \
        for (size_t i_ = 1; i_ <= n_; i_++)                            \
            argv[i_] = va_arg(ap, char *);                             \
    } while (0)

int execl(const char *path, const char *arg, ...)
{
    va_list ap;
    char **argv;
    va_start(ap, arg);
    EXECL_ARGV(arg, ap, argv);
    va_end(ap);
    return execve(path, argv, environ);
}

int execlp(const char *file, const char *arg, ...)
{
    va_list ap;
    char **argv;
    va_start(ap, arg);
    EXECL_ARGV(arg, ap, argv);
    va_end(ap);
    return execvpe(file, argv, environ);
}

int execle(const char *path, const char *arg, ...)
{
    va_list ap;
    char **argv, **envp = NULL;
    va_start(ap, arg);
    EXECL_ARGV(arg, ap, argv);
    envp = va_arg(ap, char **);
    va_end(ap);
    return execve(path, argv, envp);
}

static int spawn_common(int p, pid_t *pid, const char *path, const posix_spawn_file_actions_t *fa,
                        const posix_spawnattr_t *attr, char *const argv[], char *const envp[])
{
    __typeof__(posix_spawn) *real = p ? REAL(posix_spawnp) : REAL(posix_spawn);
    char var[32];
    uint32_t token = vc_on ? child_token() : 0;
    struct vc_slot *s = vc_on ? claim(ST_STARTING, 0, token) : NULL;
    pid_t child = 0;
    int rc;
    if (!s)
        return real(pid, path, fa, attr, argv, envp);
    snprintf(var, sizeof var, "%s=%u", VC_ENV_SLOT, slot_index(s));
    {
        char *env[env_count(envp) + 2];
        rc = real(&child, path, fa, attr, argv, with_slot(envp, var, env));
    }
    if (rc != 0) {
        unclaim(s);
    } else {
        set_child_pid(s, token, child);
        if (pid)
            *pid = child;
    }
    return rc;
}

int posix_spawn(pid_t *pid, const char *path, const posix_spawn_file_actions_t *fa, const posix_spawnattr_t *attr,
                char *const argv[], char *const envp[])
{
    return spawn_common(0, pid, path, fa, attr, argv, envp);
}

int posix_spawnp(pid_t *pid, const char *file, const posix_spawn_file_actions_t *fa, const posix_spawnattr_t *attr,
                 char *const argv[], char *const envp[])
{
    return spawn_common(1, pid, file, fa, attr, argv, envp);
}

/* ------------------------------------------------------------------ counters */

/* shim.c's write wrappers call this after every write: a write is productive, and a write to
 * something else than a bench pty may hand over to another client thread (activity). */
/* A send on fd to `to` (NULL: its peer) returned rc: counted on its channel (bytes on TCP, one datagram on
 * UDP), the channel claimed on a first send to a door. 1 if fd is a channel. */
static int chan_sent(int fd, const struct sockaddr *to, socklen_t len, ssize_t rc)
{
    int c, proto;
    if (!CHN || rc < 0 || !__atomic_load_n(&H->ndoors, __ATOMIC_RELAXED))
        return 0;
    c = chan_of(fd);
    if (to) {
        if (c >= 0 ? !is_door((int)CHN[c].proto, to, len) : !((proto = sock_proto(fd)) == IPPROTO_UDP &&
                                                                is_door(proto, to, len) &&
                                                                (c = chan_claim(fd, proto, 0, to)) >= 0))
            return 0;
    }
    if (c < 0)
        return 0;
    chan_count(&CHN[c].sent, CHN[c].proto == IPPROTO_TCP ? (uint64_t)rc : 1);
    return 1;
}

__attribute__((visibility("hidden"))) void hb_vclock_wrote(int fd, ssize_t n)
{
    int p;
    if (!vc_on || n < 0)
        return;
    if (n == 0) {  /* (an empty datagram is one) */
        chan_sent(fd, NULL, 0, 0);
        return;
    }
    productive();
    p = port_of(fd);
    if (p >= 0)
        __atomic_add_fetch(&PT[p].written, (uint64_t)n, __ATOMIC_SEQ_CST);
    else if (!chan_sent(fd, NULL, 0, n))
        bump_activity();
}

ssize_t send(int fd, const void *buf, size_t n, int flags)
{
    ssize_t rc = REAL(send)(fd, buf, n, flags);
    if (vc_on && rc >= 0) {
        int saved = errno;
        if (rc > 0)
            productive();
        if (!chan_sent(fd, NULL, 0, rc) && rc > 0)
            bump_activity();
        errno = saved;
    }
    return rc;
}

ssize_t sendto(int fd, const void *buf, size_t n, int flags, const struct sockaddr *to, socklen_t len)
{
    ssize_t rc = REAL(sendto)(fd, buf, n, flags, to, len);
    if (vc_on && rc >= 0) {
        int saved = errno;
        if (rc > 0)
            productive();
        if (!chan_sent(fd, to, len, rc) && rc > 0)
            bump_activity();
        errno = saved;
    }
    return rc;
}

ssize_t sendmsg(int fd, const struct msghdr *msg, int flags)
{
    ssize_t rc = REAL(sendmsg)(fd, msg, flags);
    if (vc_on && rc >= 0) {
        int saved = errno;
        if (rc > 0)
            productive();
        if (!chan_sent(fd, msg->msg_name, msg->msg_name ? msg->msg_namelen : 0, rc) && rc > 0)
            bump_activity();
        errno = saved;
    }
    return rc;
}

int sendmmsg(int fd, struct mmsghdr *v, unsigned int n, int flags)
{
    int rc = REAL(sendmmsg)(fd, v, n, flags), i, any = 0;
    if (vc_on && rc > 0) {
        int saved = errno;
        productive();
        for (i = 0; i < rc; i++)
            any |= chan_sent(fd, v[i].msg_hdr.msg_name, v[i].msg_hdr.msg_name ? v[i].msg_hdr.msg_namelen : 0,
                             (ssize_t)v[i].msg_len);
        if (!any)
            bump_activity();
        errno = saved;
    }
    return rc;
}

/* connect to a door: the socket is a channel from now on (also while a non-blocking connect is under way). */
int connect(int fd, const struct sockaddr *to, socklen_t len)
{
    int rc = REAL(connect)(fd, to, len), saved = errno, proto;
    if (vc_on && CHN && (rc == 0 || errno == EINPROGRESS) && (proto = sock_proto(fd)) != 0 &&
        is_door(proto, to, len))
        chan_claim(fd, proto, proto == IPPROTO_UDP, to);
    errno = saved;
    return rc;
}

/* ------------------------------------------------------------------ receiving on channels */

static int nonblocking(int fd);
static int read_empty(struct vc_slot *s, int fd);

/* Before a blocking receive on channel c: wait (virtual, SO_RCVTIMEO's timeout too) until something is there.
 * 0: go on with the real call (it will not block), -1 with errno (EAGAIN at the timeout, EINTR). */
static int chan_recv_wait(struct vc_slot *s, int fd, int flags)
{
    struct pollfd watch[2] = {{fd, POLLIN, 0}, {-1, 0, 0}};
    struct poll_ctx ctx = {watch, 1};
    struct timeval tv = {0, 0};
    socklen_t len = sizeof tv;
    int64_t timeout = -1;
    int rc;
    if (flags & MSG_DONTWAIT || nonblocking(fd))
        return 0;
    if (getsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, &len) == 0 && (tv.tv_sec || tv.tv_usec))
        timeout = ((int64_t)tv.tv_sec * 1000000 + tv.tv_usec) * 1000;
    rc = timed_fd_wait(s, poll_probe, &ctx, watch, 1, timeout, NULL, NULL);
    if (rc == 0) {
        errno = EAGAIN;
        return -1;
    }
    return rc < 0 ? -1 : 0;
}

/* What a receive on channel c returned, from `from` (NULL: unknown), counted unless it only peeked. */
static void chan_received(int c, ssize_t rc, int flags, const struct sockaddr *from, socklen_t len)
{
    struct vc_chan *r = &CHN[c];
    if (rc < 0 || flags & MSG_PEEK)
        return;
    if (r->proto == IPPROTO_TCP) {
        if (rc > 0) {
            productive();
            chan_count(&r->received, (uint64_t)rc);
        }
        return;
    }
    productive();
    if (__atomic_load_n(&r->flags, __ATOMIC_RELAXED) & CF_CONNECTED || (from && is_door(IPPROTO_UDP, from, len)))
        chan_count(&r->received, 1);
}

/* The channel behind fd and this thread's slot, or -1 (then the caller passes straight through). */
static int chan_call(int fd, struct vc_slot **s)
{
    int c;
    if (!vc_on || !CHN || !__atomic_load_n(&H->ndoors, __ATOMIC_RELAXED) || (c = chan_of(fd)) < 0 || !(*s = cur()))
        return -1;
    return c;
}

ssize_t recvfrom(int fd, void *buf, size_t n, int flags, struct sockaddr *from, socklen_t *len)
{
    struct vc_slot *s;
    struct sockaddr_in own;
    socklen_t own_len = sizeof own;
    ssize_t rc;
    int c = chan_call(fd, &s), saved;
    if (c < 0)
        return REAL(recvfrom)(fd, buf, n, flags, from, len);
    if (chan_recv_wait(s, fd, flags) < 0)
        return -1;
    if (!from || !len) {  /* (the sender tells whether a datagram is the bench's) */
        from = (struct sockaddr *)&own;
        len = &own_len;
    }
    rc = REAL(recvfrom)(fd, buf, n, flags, from, len);
    saved = errno;
    if (rc < 0 && (saved == EAGAIN || saved == EWOULDBLOCK) && read_empty(s, fd)) {  /* (polling: K in a row) */
        rc = REAL(recvfrom)(fd, buf, n, flags, from, len);
        saved = errno;
    }
    chan_received(c, rc, flags, from, *len);
    errno = saved;
    return rc;
}

ssize_t recv(int fd, void *buf, size_t n, int flags)
{
    struct vc_slot *s;
    if (chan_call(fd, &s) < 0)
        return REAL(recv)(fd, buf, n, flags);
    return recvfrom(fd, buf, n, flags, NULL, NULL);
}

ssize_t __recv_chk(int fd, void *buf, size_t n, size_t buflen, int flags)
{
    if (n > buflen)
        abort();
    return recv(fd, buf, n, flags);
}

ssize_t __recvfrom_chk(int fd, void *buf, size_t n, size_t buflen, int flags, struct sockaddr *from, socklen_t *len)
{
    if (n > buflen)
        abort();
    return recvfrom(fd, buf, n, flags, from, len);
}

ssize_t recvmsg(int fd, struct msghdr *msg, int flags)
{
    struct vc_slot *s;
    struct sockaddr_in own;
    ssize_t rc;
    int c = chan_call(fd, &s), saved, named;
    if (c < 0)
        return REAL(recvmsg)(fd, msg, flags);
    if (chan_recv_wait(s, fd, flags) < 0)
        return -1;
    named = msg->msg_name != NULL;
    if (!named) {
        msg->msg_name = &own;
        msg->msg_namelen = sizeof own;
    }
    rc = REAL(recvmsg)(fd, msg, flags);
    saved = errno;
    if (rc < 0 && (saved == EAGAIN || saved == EWOULDBLOCK) && read_empty(s, fd)) {  /* (polling: K in a row) */
        rc = REAL(recvmsg)(fd, msg, flags);
        saved = errno;
    }
    chan_received(c, rc, flags, msg->msg_name, msg->msg_namelen);
    if (!named) {
        msg->msg_name = NULL;
        msg->msg_namelen = 0;
    }
    errno = saved;
    return rc;
}

int recvmmsg(int fd, struct mmsghdr *v, unsigned int n, int flags, struct timespec *timeout)
{
    struct vc_slot *s;
    int c = chan_call(fd, &s), rc, i, saved;
    if (c < 0)
        return REAL(recvmmsg)(fd, v, n, flags, timeout);
    if (!(flags & MSG_WAITFORONE) && chan_recv_wait(s, fd, flags) < 0)
        return -1;
    rc = REAL(recvmmsg)(fd, v, n, flags, timeout);
    saved = errno;
    for (i = 0; i < rc; i++)
        chan_received(c, (ssize_t)v[i].msg_len, flags, v[i].msg_hdr.msg_name,
                      v[i].msg_hdr.msg_name ? v[i].msg_hdr.msg_namelen : 0);
    errno = saved;
    return rc;
}

/* Timers the shim does not virtualise: counted, flagged in the slot, warned once per process. */
static void unvirtualised(const char *what)
{
    struct vc_slot *s = cur();
    if (!vc_on)
        return;
    __atomic_add_fetch(&H->unvirtualised, 1, __ATOMIC_RELAXED);
    if (s)
        __atomic_or_fetch(&s->flags, SF_TIMER, __ATOMIC_RELAXED);
    if (!__atomic_exchange_n(&warned_timer, 1, __ATOMIC_RELAXED)) {
        char msg[160];
        int n = snprintf(msg, sizeof msg, "hilbench: virtual time: %s() runs on the wall clock (not virtualised)\n",
                         what);
        if (n > 0)
            (void)!syscall(SYS_write, 2, msg, (size_t)n);
    }
}

unsigned int alarm(unsigned int seconds)
{
    if (seconds)
        unvirtualised("alarm");
    return REAL(alarm)(seconds);
}

int setitimer(__itimer_which_t which, const struct itimerval *restrict nv, struct itimerval *restrict old)
{
    if (nv && (nv->it_value.tv_sec || nv->it_value.tv_usec))
        unvirtualised("setitimer");
    return REAL(setitimer)(which, nv, old);
}

int timer_settime(timer_t id, int flags, const struct itimerspec *restrict nv, struct itimerspec *restrict old)
{
    if (nv && (nv->it_value.tv_sec || nv->it_value.tv_nsec))
        unvirtualised("timer_settime");
    return REAL(timer_settime)(id, flags, nv, old);
}

int timerfd_settime(int fd, int flags, const struct itimerspec *nv, struct itimerspec *old)
{
    if (nv && (nv->it_value.tv_sec || nv->it_value.tv_nsec))
        unvirtualised("timerfd_settime");
    return REAL(timerfd_settime)(fd, flags, nv, old);
}

/* ------------------------------------------------------------------ reads of bench ptys */

static int nonblocking(int fd) { return (int)syscall(SYS_fcntl, fd, F_GETFL) & O_NONBLOCK; }

static int inq(int fd)
{
    int n = 0;
    if (hb_serve_on() && (n = hb_serve_avail(fd)) >= 0)
        return n;  /* a served pty: its own queue and the ring */
    return syscall(SYS_ioctl, fd, FIONREAD, &n) == 0 ? n : -1;
}

/* The real read, or on a served pty a take from its queue and ring (EAGAIN when empty and O_NONBLOCK, as
 * the pty; a blocking read gets here only once pty_wait found what it waits for, or VMIN = VTIME = 0). */
static ssize_t port_read(int fd, void *buf, size_t n, int served)
{
    ssize_t got;
    if (!served)
        return REAL(read)(fd, buf, n);
    got = hb_serve_take(fd, buf, n);
    if (got == 0 && n > 0 && nonblocking(fd)) {
        errno = EAGAIN;
        return -1;
    }
    return got;
}

/* readv of a served pty: port_read into one buffer, then scattered. */
static ssize_t port_readv(int fd, const struct iovec *iov, int iovcnt, size_t total)
{
    unsigned char *tmp;
    ssize_t got;
    size_t off = 0;
    int i;
    if (total > (1 << 20))
        total = 1 << 20;  /* more than the ring and a pty's queue hold */
    if (iovcnt == 1)
        return port_read(fd, iov[0].iov_base, total, 1);
    if (!(tmp = malloc(total ? total : 1)))
        return REAL(readv)(fd, iov, iovcnt);
    got = port_read(fd, tmp, total, 1);
    for (i = 0; got > 0 && i < iovcnt && off < (size_t)got; i++) {
        size_t k = (size_t)got - off < iov[i].iov_len ? (size_t)got - off : iov[i].iov_len;
        memcpy(iov[i].iov_base, tmp + off, k);
        off += k;
    }
    free(tmp);
    return got;
}

/* Before a blocking read of a bench pty returns, the bytes it would wait for are there: VMIN and
 * VTIME in virtual time. The slot waits on the port (the loop wakes it when it delivers there) and,
 * while nothing is unread, on the descriptor itself. Afterwards the real read cannot block: it asks
 * for no more than is there when fewer than VMIN bytes are. Returns the size to read, 0 for a VTIME
 * timeout without data, -1 with errno (EINTR). */
static ssize_t pty_wait(struct vc_slot *s, int fd, int port, size_t n)
{
    struct termios t;
    int64_t vtime;
    uint64_t deadline = NO_DEADLINE;
    size_t want;
    int vmin, last = 0, wfd;
    if (n == 0 || syscall(SYS_ioctl, fd, TCGETS, &t) != 0)
        return (ssize_t)n;
    if (t.c_lflag & ICANON) {  /* poll says readable only with a whole line: wait for that */
        struct pollfd watch[2] = {{fd, POLLIN, 0}, {-1, 0, 0}};
        struct poll_ctx ctx = {watch, 1};
        int rc = fd_wait(s, poll_probe, &ctx, watch, 1, NO_DEADLINE, NULL);
        return rc < 0 ? -1 : (ssize_t)n;
    }
    vmin = t.c_cc[VMIN];
    vtime = (int64_t)t.c_cc[VTIME] * (NS / 10);
    if (vmin == 0 && vtime == 0)
        return (ssize_t)n;  /* never blocks */
    want = vmin ? ((size_t)vmin < n ? (size_t)vmin : n) : 1;
    if (vmin == 0)
        deadline = add_sat(vnow(), vtime);
    wfd = wake_fd(s);
    for (;;) {
        uint64_t act = activity();
        int avail = inq(fd);
        struct pollfd watch[2];
        nfds_t k = 0;
        if (avail < 0 || (size_t)avail >= want)
            break;
        if (vmin && vtime && avail > last) {  /* the inter-byte timer starts again at each byte */
            last = avail;
            deadline = add_sat(vnow(), vtime);
        }
        if (vnow() >= deadline) {
            end_wait(s);
            return avail;  /* VTIME ran out: what is there (0: none) */
        }
        begin_wait(s, deadline, SF_FDWAIT, port < 64 ? 1ull << port : 0, act, ST_WAITING);
        if (inq(fd) != avail || vnow() >= deadline)
            continue;
        if (avail == 0) {
            watch[k].fd = fd;
            watch[k].events = POLLIN;
            watch[k++].revents = 0;
        }
        if (wfd >= 0) {
            watch[k].fd = wfd;
            watch[k].events = POLLIN;
            watch[k++].revents = 0;
        }
        if (wfd < 0) {
            struct timespec slice = ns_ts(SLICE_NS);
            REAL(ppoll)(watch, k, &slice, NULL);
        } else if (REAL(ppoll)(watch, k, NULL, NULL) < 0 && errno == EINTR) {
            end_wait(s);
            return -1;
        }
        drain_wake_fd();
    }
    end_wait(s);
    return (ssize_t)n;
}

static void count_read(int port, ssize_t got)
{
    if (got > 0) {
        productive();
        if (port >= 0)
            __atomic_add_fetch(&PT[port].read, (uint64_t)got, __ATOMIC_SEQ_CST);
    }
}

/* A read that found nothing (EAGAIN, or 0 from a VMIN=0/VTIME=0 pty): polling, K times in a row. */
static int read_empty(struct vc_slot *s, int fd)
{
    struct pollfd watch[2] = {{fd, POLLIN, 0}, {-1, 0, 0}};
    struct poll_ctx ctx = {watch, 1};
    if (!unproductive(s))
        return 0;
    fd_wait(s, poll_probe, &ctx, watch, 1, add_sat(vnow(), (int64_t)quantum()), NULL);
    return 1;
}

ssize_t read(int fd, void *buf, size_t n)
{
    struct vc_slot *s;
    ssize_t got, size = (ssize_t)n;
    int port, saved, served;
    if (!vc_on && hb_serve_on()) {
        int handled;
        got = hb_serve_read(fd, buf, n, &handled);
        if (handled)
            return got;
    }
    if (!vc_on || !(s = cur()))
        return REAL(read)(fd, buf, n);
    port = port_of(fd);
    if (port < 0 && CHN && chan_of(fd) >= 0)
        return recvfrom(fd, buf, n, 0, NULL, NULL);  /* (a read of a socket is a recv without flags) */
    served = port >= 0 && hb_serve_on() && hb_serve_avail(fd) >= 0;
    if (port >= 0 && !nonblocking(fd)) {
        size = pty_wait(s, fd, port, n);
        if (size <= 0)
            return size;
    }
    got = port_read(fd, buf, (size_t)size, served);
    saved = errno;
    count_read(port, got);
    if ((got < 0 && (saved == EAGAIN || saved == EWOULDBLOCK)) || (got == 0 && port >= 0 && n > 0)) {
        if (read_empty(s, fd)) {
            got = port_read(fd, buf, n, served);
            saved = errno;
            count_read(port, got);
        }
    }
    errno = saved;
    return got;
}

ssize_t __read_chk(int fd, void *buf, size_t n, size_t buflen)
{
    if (n > buflen)
        abort();
    return read(fd, buf, n);
}

ssize_t readv(int fd, const struct iovec *iov, int iovcnt)
{
    struct vc_slot *s;
    ssize_t got;
    size_t total = 0;
    int port, i, served;
    if (!vc_on && hb_serve_on() && iovcnt > 0) {  /* served: into one buffer, then scattered */
        int handled;
        unsigned char *tmp;
        size_t want = 0, off = 0;
        for (i = 0; i < iovcnt; i++)
            want += iov[i].iov_len;
        if (want > (1 << 20))
            want = 1 << 20;  /* more than the ring and a pty's queue hold */
        if (iovcnt == 1)
            tmp = iov[0].iov_base;
        else if (!(tmp = malloc(want ? want : 1)))
            return REAL(readv)(fd, iov, iovcnt);
        got = hb_serve_read(fd, tmp, want, &handled);
        if (handled && got > 0 && iovcnt > 1)
            for (i = 0; i < iovcnt && off < (size_t)got; i++) {
                size_t k = (size_t)got - off < iov[i].iov_len ? (size_t)got - off : iov[i].iov_len;
                memcpy(iov[i].iov_base, tmp + off, k);
                off += k;
            }
        if (iovcnt > 1)
            free(tmp);
        if (handled)
            return got;
    }
    if (!vc_on || !(s = cur()))
        return REAL(readv)(fd, iov, iovcnt);
    port = port_of(fd);
    served = port >= 0 && iovcnt > 0 && hb_serve_on() && hb_serve_avail(fd) >= 0;
    for (i = 0; i < iovcnt; i++)
        total += iov[i].iov_len;
    if (port >= 0 && !nonblocking(fd)) {
        ssize_t size = pty_wait(s, fd, port, total);
        if (size <= 0)
            return size;
        if ((size_t)size < total) {  /* fewer than VMIN: read only what is there */
            got = served ? port_readv(fd, iov, iovcnt, (size_t)size)
                         : REAL(read)(fd, iov[0].iov_base, (size_t)size < iov[0].iov_len ? (size_t)size : iov[0].iov_len);
            count_read(port, got);
            return got;
        }
    }
    got = served ? port_readv(fd, iov, iovcnt, total) : REAL(readv)(fd, iov, iovcnt);
    count_read(port, got);
    if (port < 0 && CHN && got >= 0 && (i = chan_of(fd)) >= 0) {
        int saved = errno;
        chan_received(i, got, 0, NULL, 0);
        errno = saved;
    }
    return got;
}

/* shim.c: before an input flush (tcflush, TCFLSH), what it drops is counted for the loop. */
__attribute__((visibility("hidden"))) void hb_vclock_flushing(int fd, int queue)
{
    int port, n;
    if (!vc_on || (queue != TCIFLUSH && queue != TCIOFLUSH) || (port = port_of(fd)) < 0)
        return;
    n = inq(fd);
    if (n > 0)
        __atomic_add_fetch(&PT[port].discarded, (uint64_t)n, __ATOMIC_SEQ_CST);
}

/* shim.c: FIONREAD said 0. On a bench pty, K times in a row is polling: block a quantum (1: ask again). */
__attribute__((visibility("hidden"))) int hb_vclock_empty(int fd)
{
    struct vc_slot *s;
    if (!vc_on || port_of(fd) < 0 || !(s = cur()))
        return 0;
    return read_empty(s, fd);
}
