/*
 * The core under AddressSanitizer and UndefinedBehaviorSanitizer: N random operations -- request
 * frames with random fields (some damaged, some cut short), byte soup, sample instants with random
 * counts, reply buffers too small -- and nothing may read or write out of bounds or overflow.
 *
 *   make -C firmware fuzz            (N = 1 000 000; ./build/host/rw_fuzz N for another)
 */
#include <stdio.h>
#include <stdlib.h>

#include "rw_core.h"

static uint32_t state = 12345u;

static uint32_t rnd(void) /* xorshift32 */
{
    state ^= state << 13;
    state ^= state >> 17;
    state ^= state << 5;
    return state;
}

int main(int argc, char **argv)
{
    long n_ops = argc > 1 ? atol(argv[1]) : 1000000L;
    rw_config cfg = {4000u, 4000u, 1000u, 10000u, 50u, 1u, 527u};
    static rw_core c;
    if (rw_core_init(&c, &cfg, NULL, NULL) != 0)
        return 1;
    uint8_t buf[300], out[RW_REPLY_CAP(300)], sample[64];
    uint32_t t = 0;
    int32_t pend = 0;
    uint16_t seq = 0;
    for (long i = 0; i < n_ops; i++) {
        uint32_t r = rnd() % 10u;
        if (r < 5u) {
            /* a request frame with random fields; a COMMAND answers a recent sample */
            uint8_t payload[8];
            uint8_t type = (uint8_t)(1u + rnd() % 5u);
            for (int k = 0; k < 8; k++)
                payload[k] = (uint8_t)rnd();
            if (type == RW_COMMAND)
                rw_put_u32(payload, c.k - rnd() % 4u);
            if (type == RW_HELLO)
                payload[0] = 1;
            size_t n = rw_frame_encode(buf, sizeof buf, type, seq++, payload,
                                       (uint8_t)rw_payload_size(type, RW_TO_DEVICE));
            if (rnd() % 4u == 0)
                buf[rnd() % n] ^= (uint8_t)(1u << (rnd() % 8u));        /* damaged */
            size_t len = rnd() % 3u ? n : rnd() % n;                     /* or cut short */
            size_t cap = rnd() % 2u ? sizeof out : rnd() % 40u;          /* or no room */
            t += rnd() % 200u;
            rw_core_receive(&c, buf, len, t, out, cap);
        } else if (r < 7u) {
            /* byte soup, rich in sync bytes */
            size_t n = rnd() % sizeof buf;
            for (size_t k = 0; k < n; k++)
                buf[k] = (uint8_t)(rnd() % 3u ? rnd() : RW_SYNC0);
            rw_core_receive(&c, buf, n, t, out, sizeof out);
        } else {
            /* a sample instant */
            t = (t / 1000u + 1u) * 1000u;
            rw_core_tick_begin(&c, t);
            pend += (int32_t)(rnd() % 2001u) - 1000;
            rw_core_tick_end(&c, t, pend, (int32_t)(rnd() & 0x7FFFFFFFu), sample,
                             rnd() % 8u ? sizeof sample : rnd() % 40u);
            (void)rw_core_drive(&c);
        }
    }
    rw_snapshot s;
    rw_core_snapshot(&c, &s);
    printf("rw_fuzz: %ld operations, no sanitizer finding: %u samples, %u commands taken, %u frames / "
           "%u bytes received, %u refused, %u watchdog trips, %u replies without room\n",
           n_ops, s.samples, s.commands, s.rx_frames, s.rx_bytes, s.refused, s.watchdog_trips,
           s.tx_overflow);
    return 0;
}
