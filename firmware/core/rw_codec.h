/*
 * Frame codec of the rwpend protocol: CRC-16/CCITT-FALSE, little-endian fields, framing and
 * the receiver rules (PROTOCOL.md "Frame"). Portable C99, no hardware, no allocation.
 */
#ifndef RW_CODEC_H
#define RW_CODEC_H

#include <stddef.h>
#include <stdint.h>

#include "rw_protocol.h"

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, xorout 0 ("Frame"). */
uint16_t rw_crc16(const uint8_t *p, size_t n);

/* Little-endian fields ("Physical layer": all integers are little-endian). */
static inline void rw_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static inline void rw_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

static inline uint16_t rw_get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (uint16_t)p[1] << 8);
}

static inline uint32_t rw_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* Two's complement views of the wire's unsigned fields, without relying on the
 * implementation-defined conversion of an out-of-range value to a signed type. */
static inline int32_t rw_s32(uint32_t v)
{
    return v <= 0x7FFFFFFFu ? (int32_t)v : -(int32_t)(~v) - 1;
}

static inline int16_t rw_s16(uint16_t v)
{
    return v <= 0x7FFFu ? (int16_t)v : (int16_t)(-(int16_t)(uint16_t)~v - 1);
}

/* Payload size of a message type for a direction (RW_TO_DEVICE / RW_TO_HOST), or -1 when the
 * type is unknown or not one of that direction. */
int rw_payload_size(uint8_t type, int direction);

/* One frame into out[0 .. cap): sync, type, len, seq, payload, CRC. Returns its length, or 0
 * when it does not fit or len > RW_MAX_PAYLOAD (nothing is written then). */
size_t rw_frame_encode(uint8_t *out, size_t cap, uint8_t type, uint16_t seq,
                       const uint8_t *payload, uint8_t len);

/* What the receiver refused, by PROTOCOL.md's receiver rules (names as the PC side's
 * ParserStats). Counters wrap at 2^32. */
typedef struct {
    uint32_t frames;          /* valid frames delivered */
    uint32_t bad_crc;         /* complete frames whose CRC did not match */
    uint32_t bad_length;      /* len > 64, or not the payload size of its type */
    uint32_t truncated;       /* a new A5 5A began inside the frame, or flushed partial */
    uint32_t unknown_type;    /* valid CRC, type unknown or not of this direction */
    uint32_t garbage_bytes;   /* bytes skipped while looking for a sync */
    uint32_t bytes;           /* bytes fed */
} rw_rx_stats;

/* The errors that make up the device's rx_bad (with the refused well-formed frames). */
uint32_t rw_rx_errors(const rw_rx_stats *st);

typedef struct {
    uint8_t type;
    uint8_t len;
    uint16_t seq;
    uint8_t payload[RW_MAX_PAYLOAD];
} rw_frame;

/* Incremental receiver. The buffer never holds more than one frame: after every byte put in,
 * rw_parser_next() is called until it returns 0, which leaves at most a partial frame. */
typedef struct {
    uint8_t buf[RW_MAX_FRAME];
    uint8_t n;                /* bytes in buf */
    uint8_t direction;        /* the direction accepted (RW_TO_DEVICE on the device) */
    rw_rx_stats st;
} rw_parser;

void rw_parser_init(rw_parser *p, int direction);

/* One received byte in. Call rw_parser_next() until it returns 0 before the next byte. */
void rw_parser_put(rw_parser *p, uint8_t byte);

/* The next valid frame from what was put in (1, copied to *out), or 0: more bytes needed.
 * Refused frames are counted in p->st and never returned. */
int rw_parser_next(rw_parser *p, rw_frame *out);

/* The link dropped: a partial frame counts as truncated (bytes without a sync as garbage). */
void rw_parser_flush(rw_parser *p);

#endif /* RW_CODEC_H */
