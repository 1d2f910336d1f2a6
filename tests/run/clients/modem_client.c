/* A serial client as C and C++ drivers write them (RPLIDAR SDK, ROS drivers): plain libc calls on a
 * port. Built and run by tests/run/test_c_client.py, under `hilbench run` and without it.
 * Usage: modem_client BENCH_PORT OTHER_PTY PAYLOAD_BYTES
 * Prints one line per call: NAME RC ERRNO VALUE. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

static void report(const char *what, int rc, int value)
{
    printf("%s %d %d %d\n", what, rc, rc ? errno : 0, value);
    fflush(stdout);
}

int main(int argc, char **argv)
{
    struct termios t;
    int fd, other, bits, mask = 0, n, i, off = 0;
    char *payload;

    if (argc != 4)
        return 2;
    fd = open(argv[1], O_RDWR | O_NOCTTY);
    if (fd < 0) {
        perror(argv[1]);
        return 1;
    }
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    cfsetispeed(&t, B115200);
    cfsetospeed(&t, B115200);
    t.c_cflag |= PARENB;  /* 8E1, as Modbus devices want */
    report("tcsetattr", tcsetattr(fd, TCSANOW, &t), 0);
    bits = TIOCM_DTR;
    report("TIOCMBIC-dtr", ioctl(fd, TIOCMBIC, &bits), 0);
    bits = TIOCM_RTS;
    report("TIOCMBIC-rts", ioctl(fd, TIOCMBIC, &bits), 0);
    n = ioctl(fd, TIOCMGET, &mask);  /* before report(): argument order is unspecified */
    report("TIOCMGET", n, mask);
    bits = TIOCM_DTR;
    report("TIOCMBIS-dtr", ioctl(fd, TIOCMBIS, &bits), 0);
    bits = TIOCM_RTS;
    report("TIOCMSET-rts", ioctl(fd, TIOCMSET, &bits), 0);
    report("tcsendbreak", tcsendbreak(fd, 0), 0);
    report("TIOCSBRK", ioctl(fd, TIOCSBRK), 0);
    report("TIOCCBRK", ioctl(fd, TIOCCBRK), 0);
    n = atoi(argv[3]);
    payload = malloc((size_t)n);
    for (i = 0; i < n; i++)
        payload[i] = (char)('A' + i % 26);
    while (off < n) {
        ssize_t w = write(fd, payload + off, (size_t)(n - off));
        if (w < 0)
            break;
        off += (int)w;
    }
    report("write", off == n ? 0 : -1, off);
    report("tcflush", tcflush(fd, TCOFLUSH), 0);  /* pypot does this before every packet */
    memset(&t, 0, sizeof t);
    tcgetattr(fd, &t);
    report("parenb", 0, (t.c_cflag & PARENB) != 0);
    other = open(argv[2], O_RDWR | O_NOCTTY);  /* not a bench pty: left alone */
    mask = 0;
    n = ioctl(other, TIOCMGET, &mask);
    report("other-TIOCMGET", n, mask);
    free(payload);
    return 0;
}
