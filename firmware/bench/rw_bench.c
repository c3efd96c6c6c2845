/*
 * The core's cost per sample on this PC: one COMMAND frame received (answering the last
 * sample, as the driver sends it) + one sample instant (tick_begin, tick_end: a SAMPLE frame),
 * enabled, the watchdog fed. Prints the mean over N samples and the slowest ones; the slowest
 * single iteration includes whatever the OS did meanwhile (an interrupt, a preemption), so the
 * 99.9th percentile is the honest "worst case" of the code itself.
 *
 *   make -C firmware bench            (N = 1 000 000; ./build/host/rw_bench N for another)
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "rw_core.h"

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static int cmp(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    long n = argc > 1 ? atol(argv[1]) : 1000000L;
    if (n < 1000) {
        fprintf(stderr, "usage: rw_bench [N >= 1000]\n");
        return 2;
    }
    rw_config cfg = {4000u, 4000u, 1000u, 10000u, RW_WATCHDOG_POWER_UP_MS, 0x52570001u, 527u};
    static rw_core core;
    if (rw_core_init(&core, &cfg, NULL, NULL) != 0)
        return 1;
    uint8_t out[256], sample[RW_SAMPLE_FRAME_SIZE], cmd[RW_OVERHEAD + RW_COMMAND_SIZE];
    uint8_t en_payload = 1, en[RW_OVERHEAD + RW_ENABLE_SIZE];
    uint16_t seq = 0;
    size_t m = rw_frame_encode(en, sizeof en, RW_ENABLE, seq++, &en_payload, 1);
    rw_core_receive(&core, en, m, 0, out, sizeof out);

    float *each = malloc((size_t)n * sizeof *each);
    if (!each)
        return 1;
    uint32_t t_us = 0;
    size_t bytes = 0;
    double mean = 0.0;
    /* pass 0: the loop alone (mean); pass 1: each iteration timed (its distribution) */
    for (int pass = 0; pass < 2; pass++) {
        double start = now_ns();
        for (long i = 0; i < n; i++) {
            double t0 = pass ? now_ns() : 0.0;
            uint8_t p[RW_COMMAND_SIZE];
            rw_put_u32(p, core.k);                       /* answers the newest sample */
            rw_put_u16(p + 4, (uint16_t)(int16_t)((i % 2001) - 1000));
            m = rw_frame_encode(cmd, sizeof cmd, RW_COMMAND, seq++, p, sizeof p);
            t_us += 1000u;
            bytes += rw_core_receive(&core, cmd, m, t_us - 500u, out, sizeof out);
            rw_core_tick_begin(&core, t_us);
            bytes += rw_core_tick_end(&core, t_us, (int32_t)i, (int32_t)(-i), sample, sizeof sample);
            if (pass)
                each[i] = (float)(now_ns() - t0);
        }
        if (!pass)
            mean = (now_ns() - start) / (double)n;
    }
    if (!core.enabled || core.n.commands != 2u * (uint32_t)n || core.n.samples != 2u * (uint32_t)n) {
        fprintf(stderr, "rw_bench: the core did not take every command (%u of %ld)\n",
                core.n.commands, 2 * n);
        return 1;
    }
    qsort(each, (size_t)n, sizeof *each, cmp);
    printf("rw_bench: %ld samples x 2 (COMMAND frame in + tick + SAMPLE frame out; the host builds "
           "each COMMAND frame too), %zu bytes out\n", n, bytes);
    printf("  mean %.1f ns/sample; each timed (+ ~2 clock reads): median %.0f ns, p99 %.0f ns, "
           "p99.9 %.0f ns, p99.99 %.0f ns, max %.0f ns (the max includes the OS's interruptions)\n",
           mean, (double)each[n / 2], (double)each[n * 99 / 100], (double)each[n * 999 / 1000],
           (double)each[n - n / 10000], (double)each[n - 1]);
    /* the worst input one period can bring at 921 600 baud (92 bytes per ms): 9 HELLO frames
     * (10 bytes each), each answered with a 32-byte HELLO_REPLY, then the sample instant */
    uint8_t hellos[9 * (RW_OVERHEAD + RW_HELLO_SIZE)], hp[RW_HELLO_SIZE] = {RW_PROTO_MAJOR, 0};
    size_t hn = 0;
    for (int j = 0; j < 9; j++)
        hn += rw_frame_encode(hellos + hn, sizeof hellos - hn, RW_HELLO, seq++, hp, sizeof hp);
    uint8_t big[RW_REPLY_CAP(sizeof hellos)];
    long m2 = n / 10;
    double start2 = now_ns();
    for (long i = 0; i < m2; i++) {
        double t0 = now_ns();
        t_us += 1000u;
        bytes += rw_core_receive(&core, hellos, hn, t_us - 500u, big, sizeof big);
        rw_core_tick_begin(&core, t_us);
        bytes += rw_core_tick_end(&core, t_us, (int32_t)i, (int32_t)(-i), sample, sizeof sample);
        each[i] = (float)(now_ns() - t0);
    }
    double mean2 = (now_ns() - start2) / (double)m2;
    qsort(each, (size_t)m2, sizeof *each, cmp);
    printf("  link full of HELLOs (9 frames in, 9 HELLO_REPLYs + 1 SAMPLE out per sample), %ld samples: "
           "mean %.1f ns/sample (incl. clock reads), median %.0f ns, p99 %.0f ns\n",
           m2, mean2, (double)each[m2 / 2], (double)each[m2 * 99 / 100]);
    free(each);
    return 0;
}
