/*
 * Frame codec: CRC, framing, receiver rules. See rw_codec.h and PROTOCOL.md "Frame".
 */
#include "rw_codec.h"

#include <string.h>

/* CRC-16/CCITT-FALSE four bits at a time: NIBBLE[i] is the CRC register after shifting the
 * 4-bit value i through poly 0x1021 (i.e. the bit-by-bit form of PROTOCOL.md applied to
 * i << 12). 32 bytes of table; the host tests check it against the bit-by-bit form and the
 * PC side's crc16 on random data. */
static const uint16_t NIBBLE[16] = {
    0x0000, 0x1021, 0x2042, 0x3063, 0x4084, 0x50A5, 0x60C6, 0x70E7,
    0x8108, 0x9129, 0xA14A, 0xB16B, 0xC18C, 0xD1AD, 0xE1CE, 0xF1EF,
};

uint16_t rw_crc16(const uint8_t *p, size_t n)
{
    uint16_t c = 0xFFFFu;                                /* init 0xFFFF */
    while (n--) {
        uint8_t b = *p++;
        c = (uint16_t)((c << 4) ^ NIBBLE[(c >> 12) ^ (b >> 4)]);
        c = (uint16_t)((c << 4) ^ NIBBLE[(c >> 12) ^ (b & 0x0Fu)]);
    }
    return c;                                            /* xorout 0 */
}

int rw_payload_size(uint8_t type, int direction)
{
    switch (type) {
#define RW_X_CASE(name, t, size, dir) \
    case t:                           \
        return (dir) == direction ? (size) : -1;
        RW_MESSAGES(RW_X_CASE)
#undef RW_X_CASE
    default:
        return -1;
    }
}

size_t rw_frame_encode(uint8_t *out, size_t cap, uint8_t type, uint16_t seq,
                       const uint8_t *payload, uint8_t len)
{
    size_t total = RW_OVERHEAD + (size_t)len;
    if (len > RW_MAX_PAYLOAD || cap < total)
        return 0;
    out[0] = RW_SYNC0;
    out[1] = RW_SYNC1;
    out[2] = type;
    out[3] = len;
    rw_put_u16(out + 4, seq);
    if (len)
        memcpy(out + RW_HEADER_SIZE, payload, len);
    /* the CRC covers bytes 2 .. 5+len: type, len, seq, payload */
    rw_put_u16(out + RW_HEADER_SIZE + len, rw_crc16(out + 2, 4u + (size_t)len));
    return total;
}

uint32_t rw_rx_errors(const rw_rx_stats *st)
{
    return st->bad_crc + st->bad_length + st->truncated + st->unknown_type;
}

void rw_parser_init(rw_parser *p, int direction)
{
    memset(p, 0, sizeof *p);
    p->direction = (uint8_t)direction;
}

void rw_parser_put(rw_parser *p, uint8_t byte)
{
    p->st.bytes++;
    if (p->n < sizeof p->buf) {
        p->buf[p->n++] = byte;
    } else {
        /* Cannot happen when rw_parser_next() ran to 0 after the previous byte (the buffer then
         * holds less than a whole frame); kept safe anyway: the oldest byte is dropped. */
        p->st.garbage_bytes++;
        memmove(p->buf, p->buf + 1, sizeof p->buf - 1u);
        p->buf[sizeof p->buf - 1u] = byte;
    }
}

static void drop(rw_parser *p, size_t k)
{
    memmove(p->buf, p->buf + k, p->n - k);
    p->n = (uint8_t)(p->n - k);
}

/* First A5 5A lying wholly within buf[from .. to), or -1. */
static int find_sync(const uint8_t *buf, size_t from, size_t to)
{
    for (size_t i = from; i + 1u < to; i++)
        if (buf[i] == RW_SYNC0 && buf[i + 1u] == RW_SYNC1)
            return (int)i;
    return -1;
}

int rw_parser_next(rw_parser *p, rw_frame *out)
{
    for (;;) {
        /* "search A5 5A" */
        int i = find_sync(p->buf, 0, p->n);
        if (i < 0) {
            /* keep a trailing A5: the next byte may complete the sync */
            size_t keep = (p->n && p->buf[p->n - 1u] == RW_SYNC0) ? 1u : 0u;
            p->st.garbage_bytes += (uint32_t)(p->n - keep);
            drop(p, p->n - keep);
            return 0;
        }
        if (i > 0) {
            p->st.garbage_bytes += (uint32_t)i;
            drop(p, (size_t)i);
        }
        if (p->n < RW_HEADER_SIZE)
            return 0;
        uint8_t type = p->buf[2], len = p->buf[3];
        /* "len > 64 -> bad length, drop one byte, search again" */
        if (len > RW_MAX_PAYLOAD) {
            p->st.bad_length++;
            drop(p, 1);
            continue;
        }
        /* "wait for the whole frame" */
        size_t total = RW_OVERHEAD + (size_t)len;
        if (p->n < total)
            return 0;
        /* "CRC mismatch -> bad CRC (or truncated when a new A5 5A starts inside the frame),
         * drop one byte, search again" */
        uint16_t crc = rw_get_u16(p->buf + RW_HEADER_SIZE + len);
        if (rw_crc16(p->buf + 2, 4u + (size_t)len) != crc) {
            if (find_sync(p->buf, 2, total) >= 0)
                p->st.truncated++;
            else
                p->st.bad_crc++;
            drop(p, 1);
            continue;
        }
        /* "unknown type or a type not accepted in this direction -> unknown type, skip the
         * frame; len not equal to the type's payload size -> bad length, skip" */
        int size = rw_payload_size(type, p->direction);
        if (size < 0) {
            p->st.unknown_type++;
            drop(p, total);
            continue;
        }
        if (len != (uint8_t)size) {
            p->st.bad_length++;
            drop(p, total);
            continue;
        }
        out->type = type;
        out->len = len;
        out->seq = rw_get_u16(p->buf + 4);
        memcpy(out->payload, p->buf + RW_HEADER_SIZE, len);
        p->st.frames++;
        drop(p, total);
        return 1;
    }
}

void rw_parser_flush(rw_parser *p)
{
    if (!p->n)
        return;
    if (p->n >= 2u && p->buf[0] == RW_SYNC0 && p->buf[1] == RW_SYNC1)
        p->st.truncated++;               /* "a partial frame left when the link drops" */
    else
        p->st.garbage_bytes += p->n;
    p->n = 0;
}
