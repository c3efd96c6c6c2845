/*
 * The device core of the rwpend firmware: PROTOCOL.md "Device behaviour (firmware contract)".
 *
 * Pure: no hardware, no clock of its own, no allocation. The board's HAL (board/stm32f4/hal.c)
 * and the PC's emulator (rwpend_driver/emulator.py, through ctypes) run the same code:
 *
 *   on bytes from the link:   n = rw_core_receive(core, bytes, len, now_us, out, cap);
 *                             send out[0..n); drive the motor with rw_core_drive(core)
 *   every sample period h:    rw_core_tick_begin(core, now_us);   watchdog, command for the period
 *                             drive the motor with rw_core_drive(core)
 *                             read the two encoder counters
 *                             n = rw_core_tick_end(core, now_us, pendulum, motor, out, cap);
 *                             send out[0..n)                      one SAMPLE frame
 *
 * now_us is the device clock in microseconds (wraps at 2^32). The two entry points must not
 * preempt each other (the board calls both at one interrupt priority).
 */
#ifndef RW_CORE_H
#define RW_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "rw_codec.h"

/* What the board (or the emulated rig) is; sent in HELLO_REPLY. The list is the one source for
 * C and for the emulator's ctypes view (rw_config_layout()). */
#define RW_CONFIG_FIELDS(X)                                                                   \
    X(uint32_t, u32, counts_per_rev_pendulum) /* quadrature counts per revolution */          \
    X(uint32_t, u32, counts_per_rev_motor)                                                    \
    X(uint32_t, u32, sample_period_us)        /* h, 1 .. 65535 (u16 in HELLO_REPLY) */        \
    X(uint32_t, u32, u_max_milli)             /* |u| clamp, 1 .. 65535 milli-units */         \
    X(uint32_t, u32, watchdog_ms)             /* at power-up: PROTOCOL.md says 50 */          \
    X(uint32_t, u32, serial)                  /* device serial number */                      \
    X(uint32_t, u32, overspeed_counts)        /* OVERSPEED when the motor counter moves more  \
                                                 than this in one period (V_max / k_m in      \
                                                 counts per h); 0: never */

typedef struct {
#define RW_X_FIELD(ctype, code, name) ctype name;
    RW_CONFIG_FIELDS(RW_X_FIELD)
#undef RW_X_FIELD
} rw_config;

/* Events for a log (the emulator prints them); the board passes no handler. */
enum rw_event_kind {
    RW_EV_ENABLE = 1,         /* amplifier on (ENABLE 1 while off) */
    RW_EV_DISABLE = 2,        /* amplifier off by ENABLE 0 */
    RW_EV_WATCHDOG_TRIP = 3,  /* a = us since the last valid COMMAND (or ENABLE), b = u_milli held */
    RW_EV_WATCHDOG_PERIOD = 4,/* a = the new period, ms */
    RW_EV_ZERO = 5,           /* a = the mask */
    RW_EV_HOLD_LIMIT = 6,     /* a = the new max_age, samples (0: none) */
    RW_EV_HOLD_EXPIRED = 7,   /* a = the held command's age, samples; b = u_milli held */
};

typedef struct {
    uint32_t kind;
    uint32_t sample;          /* the device's sample counter k then */
    uint32_t now_us;
    int32_t a;
    int32_t b;
} rw_event;

typedef void (*rw_event_fn)(void *ctx, const rw_event *ev);

/* What the amplifier gets: on/off, direction and magnitude (|u| <= u_max). The "motor sign":
 * reverse is set for u < 0 (sign-magnitude drive: direction pin + PWM duty |u| / u_max). */
typedef struct {
    uint8_t amplifier_on;
    uint8_t reverse;
    uint16_t magnitude_milli;
} rw_drive;

/* Counters of the core (wrap at 2^32). */
typedef struct {
    uint32_t commands;         /* valid COMMANDs taken */
    uint32_t ignored_commands; /* valid COMMANDs while disabled */
    uint32_t refused;          /* well-formed frames refused: future or old COMMAND, ACK result != 0 */
    uint32_t watchdog_trips;
    uint32_t hold_expired;     /* commands zeroed by the hold limit (too old to drive the motor) */
    uint32_t samples;          /* SAMPLE frames made */
    uint32_t tx_frames;        /* frames made (seq advanced) */
    uint32_t tx_bytes;
    uint32_t tx_overflow;      /* frames that did not fit the caller's buffer (dropped) */
} rw_counters;

typedef struct {
    rw_config cfg;
    rw_parser rx;
    rw_counters n;
    rw_event_fn on_event;
    void *event_ctx;

    uint32_t k;                /* sample counter, the k of the last SAMPLE sent */
    uint16_t tx_seq;           /* seq of the next frame sent */
    uint16_t watchdog_ms;
    uint16_t hold_samples;     /* SET_HOLD max_age: 0 = no limit */
    uint8_t expired;           /* the held command was zeroed by the hold limit */
    uint8_t enabled;           /* amplifier on */
    uint8_t tripped;           /* ST_WATCHDOG, latched until ENABLE 1 */
    uint8_t fresh;             /* ST_CMD_FRESH */
    uint8_t saturated;         /* ST_SATURATED */
    uint8_t zeroed;            /* ST_ZEROED */
    uint8_t have_counts;       /* a sample was read (raw_motor valid) */
    uint8_t overspeed;         /* ST_OVERSPEED of the last sample */
    int16_t u_milli;           /* held command, clamped */
    uint32_t cmd_sample;       /* sample answered by the held command, RW_NO_SAMPLE if none */
    uint32_t last_command_us;  /* device time of the last valid COMMAND or ENABLE */
    int16_t applied_milli;     /* command held over the period that ends at the next sample */
    uint32_t applied_sample;
    int32_t raw_pendulum;      /* encoder counters at the last sample, as read */
    int32_t raw_motor;
    uint32_t zero_pendulum;    /* offsets set by ZERO */
    uint32_t zero_motor;
} rw_core;

/* Worst-case reply bytes for n input bytes to rw_core_receive: each request frame (at least
 * RW_MIN_REQUEST_FRAME bytes, some of them maybe from an earlier call) gets at most a
 * HELLO_REPLY. A smaller buffer is safe: replies that do not fit are dropped and counted. */
#define RW_REPLY_CAP(n) ((((n) + RW_MAX_FRAME) / RW_MIN_REQUEST_FRAME + 1u) * \
                         (RW_OVERHEAD + RW_HELLO_REPLY_SIZE))
#define RW_SAMPLE_FRAME_SIZE (RW_OVERHEAD + RW_SAMPLE_SIZE)

/* Power-up state (disabled, encoders zero, watchdog cfg->watchdog_ms). Returns 0, or a
 * negative code for an invalid configuration (rw_config_error() says which). */
int rw_core_init(rw_core *c, const rw_config *cfg, rw_event_fn on_event, void *event_ctx);
const char *rw_config_error(int code);

/* Bytes from the PC. Returns the reply bytes written to out (HELLO_REPLY, ACK frames). */
size_t rw_core_receive(rw_core *c, const uint8_t *data, size_t n, uint32_t now_us,
                       uint8_t *out, size_t cap);

/* Start of a sample instant: watchdog check, then the held command is the motor's for the
 * period. Returns that command (milli-units, 0 when disabled). */
int32_t rw_core_tick_begin(rw_core *c, uint32_t now_us);

/* End of a sample instant: the encoder counters as read (wrapping 32-bit counts) in, SAMPLE
 * frame k+1 out. Returns its length (RW_SAMPLE_FRAME_SIZE, or 0 when cap is too small). */
size_t rw_core_tick_end(rw_core *c, uint32_t now_us, int32_t pendulum_counts,
                        int32_t motor_counts, uint8_t *out, size_t cap);

/* What the amplifier must get now. */
rw_drive rw_core_drive(const rw_core *c);

/* The link dropped (a board that can tell, e.g. USB): a partial frame counts as truncated. */
void rw_core_link_lost(rw_core *c);

/* A 16-bit hardware counter extended to the wrapping 32-bit count: prev is the last extended
 * value, raw the counter now. Exact while the counter moves less than 32768 between reads. */
int32_t rw_counter_extend16(int32_t prev, uint16_t raw);

/* Bring-up and test aid: continue the sample counter from k (the next SAMPLE is k + 1). */
void rw_core_set_sample(rw_core *c, uint32_t k);

/* Everything worth showing about the core, as flat 32-bit fields. The list is the one source
 * for C and for the emulator's ctypes view (rw_snapshot_layout()). */
#define RW_SNAPSHOT_FIELDS(X)                                                          \
    X(uint32_t, u32, sample)            /* k of the last SAMPLE */                     \
    X(uint32_t, u32, enabled)                                                          \
    X(uint32_t, u32, tripped)                                                          \
    X(int32_t, i32, u_milli)            /* held command (0 while disabled) */          \
    X(int32_t, i32, u_applied_milli)    /* in the last SAMPLE */                       \
    X(uint32_t, u32, cmd_sample)                                                       \
    X(uint32_t, u32, watchdog_ms)                                                      \
    X(int32_t, i32, pendulum_counts)    /* at the last sample, after ZERO */           \
    X(int32_t, i32, motor_counts)                                                      \
    X(uint32_t, u32, status)            /* the status bits the next SAMPLE would carry */ \
    X(uint32_t, u32, rx_bad)            /* u16 on the wire */                          \
    X(uint32_t, u32, commands)                                                         \
    X(uint32_t, u32, ignored_commands)                                                 \
    X(uint32_t, u32, refused)                                                          \
    X(uint32_t, u32, watchdog_trips)                                                   \
    X(uint32_t, u32, samples)                                                          \
    X(uint32_t, u32, tx_frames)                                                        \
    X(uint32_t, u32, tx_bytes)                                                         \
    X(uint32_t, u32, tx_overflow)                                                      \
    X(uint32_t, u32, tx_seq)                                                           \
    X(uint32_t, u32, rx_frames)                                                        \
    X(uint32_t, u32, rx_bad_crc)                                                       \
    X(uint32_t, u32, rx_bad_length)                                                    \
    X(uint32_t, u32, rx_truncated)                                                     \
    X(uint32_t, u32, rx_unknown_type)                                                  \
    X(uint32_t, u32, rx_garbage_bytes)                                                 \
    X(uint32_t, u32, rx_bytes)                                                         \
    X(uint32_t, u32, hold_samples)      /* SET_HOLD max_age (0: no limit) */           \
    X(uint32_t, u32, hold_expired)

typedef struct {
#define RW_X_FIELD(ctype, code, name) ctype name;
    RW_SNAPSHOT_FIELDS(RW_X_FIELD)
#undef RW_X_FIELD
} rw_snapshot;

void rw_core_snapshot(const rw_core *c, rw_snapshot *s);

/* "u32 sample,u32 enabled,...": the fields in order, for a foreign-function view, and sizes. */
const char *rw_snapshot_layout(void);
const char *rw_config_layout(void);
size_t rw_core_size(void);
size_t rw_snapshot_size(void);
size_t rw_config_size(void);

/* "1.1.0" (rw_version.h). */
const char *rw_fw_version(void);

#endif /* RW_CORE_H */
