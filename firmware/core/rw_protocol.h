/*
 * rwpend serial protocol 1.0 -- the wire facts of the firmware, stated once.
 *
 * Every number here is PROTOCOL.md's (rwpend_driver/PROTOCOL.md); the section names in the
 * comments are its headings. The PC side states the same facts in Python
 * (rwpend_driver/rwpend_driver/protocol.py); rwpend_driver/test/test_firmware.py checks that
 * the two agree, byte for byte. Nothing else in firmware/ spells a type number, a payload size
 * or a status bit.
 */
#ifndef RW_PROTOCOL_H
#define RW_PROTOCOL_H

#include <stdint.h>

/* ------------------------------------------------------------------ "Frame" */
#define RW_SYNC0 0xA5u                /* sync: A5 5A */
#define RW_SYNC1 0x5Au
#define RW_HEADER_SIZE 6u             /* sync (2), type (1), len (1), seq (2, little-endian) */
#define RW_CRC_SIZE 2u                /* CRC-16/CCITT-FALSE over type, len, seq, payload */
#define RW_OVERHEAD (RW_HEADER_SIZE + RW_CRC_SIZE)
#define RW_MAX_PAYLOAD 64u            /* a longer len field is a "bad length" */
#define RW_MAX_FRAME (RW_OVERHEAD + RW_MAX_PAYLOAD)

/* ------------------------------------------------------------------ "Versioning" */
#define RW_PROTO_MAJOR 1u
#define RW_PROTO_MINOR 1u

/* ------------------------------------------------------------------ "Messages"
 * X(name, type, payload size, direction). The payload layouts (field offsets) are written out
 * where each message is encoded or decoded (rw_core.c), next to PROTOCOL.md's table rows. */
#define RW_TO_DEVICE 0                /* PC -> device */
#define RW_TO_HOST 1                  /* device -> PC */

#define RW_MESSAGES(X)                              \
    X(HELLO,        0x01, 2,  RW_TO_DEVICE)         \
    X(COMMAND,      0x02, 6,  RW_TO_DEVICE)         \
    X(ENABLE,       0x03, 1,  RW_TO_DEVICE)         \
    X(SET_WATCHDOG, 0x04, 2,  RW_TO_DEVICE)         \
    X(ZERO,         0x05, 1,  RW_TO_DEVICE)         \
    X(SET_HOLD,     0x06, 2,  RW_TO_DEVICE)         \
    X(HELLO_REPLY,  0x81, 24, RW_TO_HOST)           \
    X(SAMPLE,       0x82, 26, RW_TO_HOST)           \
    X(ACK,          0x83, 4,  RW_TO_HOST)

enum rw_msg_type {
#define RW_X_TYPE(name, type, size, dir) RW_##name = type,
    RW_MESSAGES(RW_X_TYPE)
#undef RW_X_TYPE
};

enum rw_msg_size {
#define RW_X_SIZE(name, type, size, dir) RW_##name##_SIZE = size,
    RW_MESSAGES(RW_X_SIZE)
#undef RW_X_SIZE
};

/* The shortest request frame (ENABLE, ZERO: one payload byte): bounds the replies per input. */
#define RW_MIN_REQUEST_FRAME (RW_OVERHEAD + 1u)

/* ------------------------------------------------------------------ SAMPLE status bits */
#define RW_ST_ENABLED 0x0001u         /* amplifier on */
#define RW_ST_WATCHDOG 0x0002u        /* watchdog tripped, latched until ENABLE 1 */
#define RW_ST_OVERSPEED 0x0004u       /* |rotor speed relative to the pendulum| > V_max / k_m */
#define RW_ST_CMD_FRESH 0x0008u       /* a valid COMMAND arrived since the previous sample */
#define RW_ST_SATURATED 0x0010u       /* held command clamped to +-u_max */
#define RW_ST_ZEROED 0x0020u          /* a ZERO was executed since power-up */

/* ------------------------------------------------------------------ ACK results */
#define RW_R_OK 0u
#define RW_R_BAD_VALUE 1u
#define RW_R_BAD_STATE 2u
#define RW_R_UNSUPPORTED 3u

/* ------------------------------------------------------------------ field values */
#define RW_NO_SAMPLE 0xFFFFFFFFu      /* SAMPLE.cmd_sample: no command held */
#define RW_WATCHDOG_MIN_MS 2u         /* SET_WATCHDOG period_ms range */
#define RW_WATCHDOG_MAX_MS 1000u
#define RW_WATCHDOG_POWER_UP_MS 50u   /* "Device behaviour": watchdog 50 ms at power-up */
#define RW_HOLD_MAX_SAMPLES 1000u     /* SET_HOLD max_age range 0..1000 (0: no limit, at power-up) */
#define RW_ZERO_PENDULUM 0x01u        /* ZERO mask bits */
#define RW_ZERO_MOTOR 0x02u

#endif /* RW_PROTOCOL_H */
