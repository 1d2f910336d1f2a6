/* Drains as C clients make them, on a bench pty at 9600 baud (a paced bench takes ~1 ms a byte, so a
 * drain that returned early is caught). Run by tests/run/test_delivery_ledger.py under `hilbench run`.
 * Usage: drain_client PORT N. Steps, each answered by one line on stdout, each after a line on stdin:
 *   start      write "hello" (write), tcdrain                      -> "hello"
 *   idle       N x (tcdrain, TCSBRK 1, tcflush(TCOFLUSH)): nothing pending -> "idle"
 *   dup        writev on a dup()ed descriptor, tcdrain on the first -> "dup"
 *   fork       a forked child writes, exits; the parent drains     -> "fork"
 *   reopen     a new number written to as /dev/null, closed, opened as the pty: write, drain
 *                                                                 -> "reopen"
 *   stdio      fdopen + fputs + fflush (stdio: unseen), tcdrain    -> "stdio"
 *   flush      write "bye", tcflush(TCOFLUSH)                      -> "flush"
 */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/uio.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

static void step(const char *name)
{
    char line[64];
    if (!fgets(line, sizeof line, stdin))
        exit(3);
    (void)name;
}

static void done(const char *name)
{
    printf("%s\n", name);
    fflush(stdout);
}

int main(int argc, char **argv)
{
    struct termios t;
    struct iovec iov[2] = {{"du", 2}, {"p", 1}};
    int fd, fd2, fd3, i, n;
    pid_t child;
    FILE *f;

    if (argc != 3)
        return 2;
    n = atoi(argv[2]);
    fd = open(argv[1], O_RDWR | O_NOCTTY);
    if (fd < 0)
        return 1;
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    cfsetispeed(&t, B9600);
    cfsetospeed(&t, B9600);
    tcsetattr(fd, TCSANOW, &t);

    step("start");
    if (write(fd, "hello", 5) != 5)
        return 1;
    tcdrain(fd);
    done("hello");

    step("idle");
    for (i = 0; i < n; i++) {
        tcdrain(fd);
        ioctl(fd, TCSBRK, 1);
        tcflush(fd, TCOFLUSH);
    }
    done("idle");

    step("dup");
    fd2 = dup(fd);
    if (writev(fd2, iov, 2) != 3)
        return 1;
    tcdrain(fd);
    done("dup");

    step("fork");
    child = fork();
    if (child == 0) {
        _exit(write(fd, "fork", 4) == 4 ? 0 : 1);
    }
    waitpid(child, NULL, 0);
    tcdrain(fd);
    done("fork");

    step("reopen");  /* a new number written to as /dev/null, closed, then opened as the pty */
    fd3 = open("/dev/null", O_WRONLY);
    if (write(fd3, "x", 1) != 1)
        return 4;
    close(fd3);
    if (open(argv[1], O_RDWR | O_NOCTTY) != fd3 || write(fd3, "again", 5) != 5)
        return 4;
    tcdrain(fd);
    done("reopen");

    step("stdio");
    f = fdopen(dup(fd), "w");
    fputs("stdio", f);
    fflush(f);
    tcdrain(fd);
    done("stdio");

    step("flush");
    if (write(fd, "bye", 3) != 3)
        return 1;
    tcflush(fd, TCOFLUSH);
    done("flush");
    return 0;
}
