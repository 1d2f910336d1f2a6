/* A C client of a bench pty in virtual time (tests/run/test_vclock.py): blocking reads with VMIN/VTIME,
 * select and poll on the pty, a write and an input flush. Prints "NAME VIRTUAL_NS RESULT" with the
 * virtual CLOCK_MONOTONIC at which each call returned (the test schedules the bench's bytes). */
#define _GNU_SOURCE
#include <fcntl.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static long long now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1000000000LL + t.tv_nsec;
}

static void mode(int fd, int vmin, int vtime)
{
    struct termios t;
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    t.c_cc[VMIN] = (cc_t)vmin;
    t.c_cc[VTIME] = (cc_t)vtime;
    tcsetattr(fd, TCSANOW, &t);
}

int main(int argc, char **argv)
{
    char buf[64];
    int fd = open(argv[argc - 1], O_RDWR | O_NOCTTY), rc;
    fd_set r;
    struct timeval tv = {5, 0};
    struct pollfd pf;
    struct timespec until;
    if (fd < 0)
        return 1;
    mode(fd, 0, 5);
    rc = (int)read(fd, buf, sizeof buf);
    printf("read_vtime %lld %d\n", now(), rc);  /* nothing: 0 after 0.5 s */
    mode(fd, 1, 0);
    rc = (int)read(fd, buf, sizeof buf);
    printf("read_vmin1 %lld %d\n", now(), rc);  /* "abc" at 1001.0 */
    mode(fd, 5, 2);
    rc = (int)read(fd, buf, sizeof buf);
    printf("read_vmin5_vtime2 %lld %d\n", now(), rc);  /* "ab" at 1002.0, "c" at 1002.1, then 0.2 s of silence */
    FD_ZERO(&r);
    FD_SET(fd, &r);
    rc = select(fd + 1, &r, NULL, NULL, &tv);
    printf("select %lld %d\n", now(), rc);  /* "x" at 1003.0 */
    rc = (int)read(fd, buf, 1);
    printf("read_one %lld %d\n", now(), rc);
    pf.fd = fd;
    pf.events = POLLIN;
    rc = poll(&pf, 1, 250);
    printf("poll %lld %d\n", now(), rc);
    {
        int ep = epoll_create1(0);
        struct epoll_event ev = {.events = EPOLLIN, .data.fd = fd}, out[2];
        epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
        rc = epoll_wait(ep, out, 2, 5000);
        printf("epoll_wait %lld %d\n", now(), rc);  /* "e" at 1003.5 */
        close(ep);
        rc = (int)read(fd, buf, 1);
        printf("read_e %lld %d\n", now(), buf[0] == 'e' ? rc : -1);
    }
    rc = (int)write(fd, "hello", 5);
    printf("write %lld %d\n", now(), rc);
    until.tv_sec = 1004;
    until.tv_nsec = 500000000;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, NULL);  /* "zz" arrives at 1004.0 */
    rc = tcflush(fd, TCIFLUSH);
    printf("tcflush %lld %d\n", now(), rc);
    return 0;
}
