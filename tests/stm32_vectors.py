"""Test vectors of the STM32 board spec sheet (stm32_board.md): trace listings (§4.4), the synthetic
trace with expected statistics (§6.4), the report block (§6.5), and an independent CRC-32/MPEG-2 (§1.3).
One home for them, shared by the protocol, fake and profiler tests."""

from __future__ import annotations


def lines(text: str) -> bytes:
    """Spec sheet notation: ' ; ' separates LF-terminated lines."""
    return "".join(p.strip() + "\n" for p in text.replace("\n", " ; ").split(" ; ") if p.strip()).encode()


LISTING_34 = """IDLE 1 0 ; profile 2 1 ; w_ctrl 7413 1 ; w_ctrl 7504 0 ; odom 7951 1 ; odom 7969 0
profile 28 0 ; IDLE 29 1 ; IDLE 332 0 ; tsink 333 1 ; tsink 336 0"""
LISTING_35 = """IDLE 1 0 ; profile 2 1 ; profile 28 0 ; IDLE 29 1 ; IDLE 556 0 ; tsink 557 1
tsink 560 0 ; uros 561 1 ; uros 623 0 ; IDLE 625 1 ; IDLE 667 0 ; odom 6613 1 ; odom 6694 0"""
LISTING_38 = """IDLE 1 0 ; profile 2 1 ; profile 25 0 ; IDLE 27 1 ; IDLE 88 0 ; hal_fetch 89 1
hal_fetch 95 0 ; wheel_ctrl 96 1 ; wheel_ctrl 106 0 ; IDLE 107 1 ; IDLE 288 0 ; odometry 289 1
odometry 296 0 ; pose_control 297 1 ; pose_control 306 0 ; hal_fetch 307 1 ; hal_fetch 313 0 ; wheel_ctrl 313 1
odometry 788 1"""
LISTING_39 = """profile 2 1 ; profile 28 0 ; IDLE 29 1 ; IDLE 36 0 ; tsink 37 1 ; tsink 40 0
pose_control 41 1 ; pose_control 50 0 ; odometry 51 1 ; odometry 58 0 ; hal_fetch 58 1 ; hal_fetch 65 0
wheel_ctrl 65 1 ; wheel_ctrl 76 0 ; IDLE 78 1 ; IDLE 136 0 ; hal_fetch 137 1 ; hal_fetch 149 0
tsink 149 1 ; tsink 153 0 ; wheel_ctrl 154 1 ; wheel_ctrl 164 0 ; IDLE 165 1 ; IDLE 236 0
pose_control 237 1 ; pose_control 246 0"""
TRACE_64 = """IDLE 0 out ; wheel_ctrl 0 in ; pid 2 in ; pid 7 out ; wheel_ctrl 10 out ; IDLE 10 in
IDLE 1003 out ; wheel_ctrl 1003 in ; wheel_ctrl 1015 out ; IDLE 1015 in ; IDLE 1998 out ; wheel_ctrl 1998 in
wheel_ctrl 2007 out ; IDLE 2007 in ; IDLE 3010 out ; wheel_ctrl 3010 in ; pid 3012 in ; wheel_ctrl 3020 out
wheel_ctrl 3030 in ; pid 3035 out ; wheel_ctrl 3040 out ; IDLE 3040 in ; IDLE 4000 out ; wheel_ctrl 4000 in
wheel_ctrl 4011 out ; IDLE 4011 in ; IDLE 5001 out ; wheel_ctrl 5001 in ; wheel_ctrl 5011 out ; IDLE 5011 in
tsink 3020 in ; tsink 3030 out"""


# §6.5: the report block of listing 37 in branch-head layout, 26 lines, 723 bytes.
REPORT_65 = b"".join([
    b"=============================================\n", b"free heap:\t\t195696\n", b"ctx switches:\t\t76148\n",
    b"Task\t\tTime\t\t%%\n", b"profile        \t9669\t\t4%\r\n", b"IDLE           \t201086\t\t95%\r\n",
    b"hal_fetch      \t81\t\t<1%\r\n", b"wheel_ctrl     \t87\t\t<1%\r\n", b"odometry       \t49\t\t<1%\r\n",
    b"pose_control   \t51\t\t<1%\r\n", b"tsink          \t615\t\t<1%\r\n", b"Tmr Svc        \t0\t\t<1%\r\n",
    b"recv_vel       \t0\t\t<1%\r\n", b"---------------------------------------------\n",
    b"Task\t\tState\tPrio\tStack\tNum\n", b"profile        \tX\t24\t900\t7\r\n", b"IDLE           \tR\t0\t108\t8\r\n",
    b"wheel_ctrl     \tB\t24\t420\t5\r\n", b"odometry       \tB\t24\t416\t6\r\n",
    b"pose_control   \tB\t24\t410\t4\r\n", b"tsink          \tB\t32\t483\t1\r\n",
    b"hal_fetch      \tB\t24\t443\t2\r\n", b"recv_vel       \tS\t24\t441\t3\r\n",
    b"Tmr Svc        \tB\t2\t223\t9\r\n", b"=============================================\n",
    b"output took 18779120 us\n",
])


def crc32_mpeg2_bitwise(data: bytes) -> int:
    """An independent CRC-32/MPEG-2 (bitwise, not crcmod): poly 0x04C11DB7, init 0xFFFFFFFF, MSB first,
    no reflection, no xorout."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc
