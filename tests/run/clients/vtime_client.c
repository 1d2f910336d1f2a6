/* A C client of the virtual-time shim (tests/run/test_vclock.py): every way to wait that vclock.c
 * wraps, each printed as "NAME VIRTUAL_NS RESULT" with the virtual time it took (CLOCK_MONOTONIC,
 * which the shim answers), then "wall WALL_NS" (the real clock, read with a raw system call). */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <spawn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

extern char **environ;

static int64_t ns(clockid_t c)
{
    struct timespec t;
    clock_gettime(c, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static int64_t wall(void)
{
    struct timespec t;
    syscall(SYS_clock_gettime, CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static int64_t t0;
static void begin(void) { t0 = ns(CLOCK_MONOTONIC); }
static void done(const char *name, long result)
{
    printf("%s %lld %ld\n", name, (long long)(ns(CLOCK_MONOTONIC) - t0), result);
    fflush(stdout);
}

static pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t cv;
static int flag;

static void *sleeper(void *arg)
{
    usleep((useconds_t)(intptr_t)arg);
    return NULL;
}

static void *signaller(void *arg)
{
    (void)arg;
    usleep(500000);
    pthread_mutex_lock(&mu);
    flag = 1;
    pthread_cond_signal(&cv);
    pthread_mutex_unlock(&mu);
    return NULL;
}

int main(void)
{
    int64_t w0 = wall(), rt;
    struct timespec ts;
    int p[2], rc;
    pthread_condattr_t ca;
    pthread_t th;

    if (pipe(p) != 0)
        return 1;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&cv, &ca);

    begin(); ts.tv_sec = 1; ts.tv_nsec = 0; rc = nanosleep(&ts, NULL); done("nanosleep", rc);
    begin(); rc = usleep(250000); done("usleep", rc);
    begin(); rt = ns(CLOCK_REALTIME); rc = (int)sleep(2); done("sleep", rc);
    printf("realtime %lld 0\n", (long long)(ns(CLOCK_REALTIME) - rt));
    {
        time_t a = time(NULL);
        struct timeval g0, g1;
        gettimeofday(&g0, NULL);
        sleep(3);
        gettimeofday(&g1, NULL);
        printf("time %lld 0\n", (long long)(time(NULL) - a));
        printf("gettimeofday %lld 0\n",
               (long long)((g1.tv_sec - g0.tv_sec) * 1000000000LL + (g1.tv_usec - g0.tv_usec) * 1000LL));
    }
    begin();
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_sec += 1; ts.tv_nsec += 500000000;
    if (ts.tv_nsec >= 1000000000) { ts.tv_sec++; ts.tv_nsec -= 1000000000; }
    rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    done("clock_nanosleep_abs", rc);
    begin();
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_nsec += 500000000;
    if (ts.tv_nsec >= 1000000000) { ts.tv_sec++; ts.tv_nsec -= 1000000000; }
    rc = clock_nanosleep(CLOCK_REALTIME, TIMER_ABSTIME, &ts, NULL);
    done("clock_nanosleep_abs_realtime", rc);
    begin(); ts.tv_sec = 0; ts.tv_nsec = 125000000; rc = clock_nanosleep(CLOCK_MONOTONIC, 0, &ts, NULL);
    done("clock_nanosleep_rel", rc);
    {
        fd_set r;
        struct timeval tv = {0, 700000};
        FD_ZERO(&r);
        FD_SET(p[0], &r);
        begin(); rc = select(p[0] + 1, &r, NULL, NULL, &tv); done("select", rc);
        printf("select_left %lld 0\n", (long long)(tv.tv_sec * 1000000000LL + tv.tv_usec * 1000LL));
    }
    {
        struct pollfd pf = {p[0], POLLIN, 0};
        begin(); rc = poll(&pf, 1, 300); done("poll", rc);
    }
    {
        int ep = epoll_create1(0);
        struct epoll_event ev = {.events = EPOLLIN, .data.fd = p[0]}, out[4];
        epoll_ctl(ep, EPOLL_CTL_ADD, p[0], &ev);
        begin(); rc = epoll_wait(ep, out, 4, 1200); done("epoll_wait", rc);
        /* a byte written by another thread at 0.25 s ends a 5 s wait at 0.25 s */
        pthread_create(&th, NULL, sleeper, (void *)(intptr_t)250000);
        begin();
        pthread_join(th, NULL);
        if (write(p[1], "x", 1) != 1)
            return 1;
        rc = epoll_wait(ep, out, 4, 5000);
        done("epoll_wait_ready", rc);
        close(ep);
        char c;
        if (read(p[0], &c, 1) != 1)
            return 1;
    }
    pthread_mutex_lock(&mu);
    begin();
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_nsec += 400000000;
    if (ts.tv_nsec >= 1000000000) { ts.tv_sec++; ts.tv_nsec -= 1000000000; }
    do rc = pthread_cond_timedwait(&cv, &mu, &ts); while (rc == 0);
    done("pthread_cond_timedwait", rc == ETIMEDOUT);
    begin();
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_nsec += 600000000;
    if (ts.tv_nsec >= 1000000000) { ts.tv_sec++; ts.tv_nsec -= 1000000000; }
    do rc = pthread_cond_clockwait(&cv, &mu, CLOCK_MONOTONIC, &ts); while (rc == 0);
    done("pthread_cond_clockwait", rc == ETIMEDOUT);
    /* signalled by another thread at 0.5 s, deadline at 5 s */
    pthread_create(&th, NULL, signaller, NULL);
    begin();
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_sec += 5;
    rc = 0;
    while (!flag && rc == 0)
        rc = pthread_cond_timedwait(&cv, &mu, &ts);
    done("pthread_cond_signalled", flag && rc == 0);
    pthread_mutex_unlock(&mu);
    pthread_join(th, NULL);
    {
        sem_t s;
        sem_init(&s, 0, 0);
        begin();
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_nsec += 300000000;
        if (ts.tv_nsec >= 1000000000) { ts.tv_sec++; ts.tv_nsec -= 1000000000; }
        rc = sem_timedwait(&s, &ts);
        done("sem_timedwait", rc == -1 && errno == ETIMEDOUT);
    }
    pthread_create(&th, NULL, sleeper, (void *)(intptr_t)750000);
    begin(); pthread_join(th, NULL); done("pthread_join", 0);
    {
        int status = -1;
        pid_t pid;
        begin();
        pid = fork();
        if (pid == 0) {
            execl("/bin/sleep", "sleep", "2", (char *)NULL);
            _exit(127);
        }
        waitpid(pid, &status, 0);
        done("fork_exec_sleep", status);
        char *argv[] = {"sleep", "1", NULL};
        begin();
        rc = posix_spawn(&pid, "/bin/sleep", NULL, NULL, argv, environ);
        waitpid(pid, &status, 0);
        done("posix_spawn_sleep", rc == 0 ? status : -1);
    }
    printf("wall %lld 0\n", (long long)(wall() - w0));
    return 0;
}
