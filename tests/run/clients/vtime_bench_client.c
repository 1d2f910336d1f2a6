/* A C client of a virtual-time bench under `hilbench run` (tests/run/test_virtual_time.py, PLAN26 §9.1 e):
 * every way a C program waits, each measured in virtual ns with clock_gettime(CLOCK_MONOTONIC) (which the
 * preload shim answers from the bench's clock): sleeps, an absolute clock_nanosleep, select/poll/epoll_wait
 * timeouts on the bench pty with nothing to read, a VMIN=0/VTIME read on it, condition variable timeouts,
 * and fork + exec of /bin/sleep 2 waited with waitpid. Prints one JSON line: the durations, each call's
 * result, the virtual total and the wall time (the real clock, read with a raw system call).
 * usage: vtime_bench_client PTY */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define NS 1000000000LL

static int64_t vnow(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * NS + t.tv_nsec;
}

static int64_t wall(void)
{
    struct timespec t;
    syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * NS + t.tv_nsec;
}

static struct timespec after(clockid_t c, int64_t ns)
{
    struct timespec t;
    clock_gettime(c, &t);
    ns += t.tv_nsec;
    t.tv_sec += ns / NS;
    t.tv_nsec = ns % NS;
    return t;
}

static int64_t t0;
static int first = 1;
static void begin(void) { t0 = vnow(); }
static void done(const char *name, long result)
{
    printf("%s\"%s\": [%lld, %ld]", first ? "{" : ", ", name, (long long)(vnow() - t0), result);
    first = 0;
}

int main(int argc, char **argv)
{
    int64_t w0 = wall(), v0 = vnow();
    struct timespec ts;
    struct termios tio;
    pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
    pthread_condattr_t ca;
    pthread_cond_t cv;
    char buf[64];
    int fd, rc;

    if (argc != 2 || (fd = open(argv[1], O_RDWR | O_NOCTTY)) < 0)
        return 2;
    tcgetattr(fd, &tio);
    cfmakeraw(&tio);
    cfsetspeed(&tio, B115200);
    tcsetattr(fd, TCSANOW, &tio);

    begin(); ts.tv_sec = 1; ts.tv_nsec = 0; rc = nanosleep(&ts, NULL); done("nanosleep", rc);
    begin(); rc = usleep(250000); done("usleep", rc);
    begin(); rc = (int)sleep(2); done("sleep", rc);
    begin();
    ts = after(CLOCK_MONOTONIC, 1500000000LL);
    rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    done("clock_nanosleep_abs", rc);
    {
        fd_set r;
        struct timeval tv = {0, 700000};
        FD_ZERO(&r);
        FD_SET(fd, &r);
        begin(); rc = select(fd + 1, &r, NULL, NULL, &tv); done("select_pty", rc);
        done("select_left_us", tv.tv_sec * 1000000L + tv.tv_usec);  /* Linux writes back what was left: 0 */
    }
    {
        struct pollfd pf = {fd, POLLIN, 0};
        begin(); rc = poll(&pf, 1, 300); done("poll_pty", rc);
    }
    {
        int ep = epoll_create1(0);
        struct epoll_event ev = {.events = EPOLLIN, .data.fd = fd}, out[2];
        epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
        begin(); rc = epoll_wait(ep, out, 2, 1200); done("epoll_wait_pty", rc);
        close(ep);
    }
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 5;  /* tenths of a second: 0.5 s */
    tcsetattr(fd, TCSANOW, &tio);
    begin(); rc = (int)read(fd, buf, sizeof buf); done("read_vtime", rc);

    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&cv, &ca);
    pthread_mutex_lock(&mu);
    begin();
    ts = after(CLOCK_MONOTONIC, 600000000LL);
    do rc = pthread_cond_clockwait(&cv, &mu, CLOCK_MONOTONIC, &ts); while (rc == 0);
    done("pthread_cond_clockwait", rc == ETIMEDOUT);
    begin();
    ts = after(CLOCK_MONOTONIC, 400000000LL);
    do rc = pthread_cond_timedwait(&cv, &mu, &ts); while (rc == 0);
    done("pthread_cond_timedwait", rc == ETIMEDOUT);
    pthread_mutex_unlock(&mu);
    {
        int status = -1;
        pid_t pid;
        begin();
        pid = fork();
        if (pid == 0) {
            execl("/bin/sleep", "sleep", "2", (char *)NULL);
            _exit(127);
        }
        rc = waitpid(pid, &status, 0) == pid ? status : -1;
        done("fork_exec_sleep", rc);
    }
    printf(", \"total\": %lld, \"wall\": %lld}\n", (long long)(vnow() - v0), (long long)(wall() - w0));
    return 0;
}
