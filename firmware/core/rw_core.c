/*
 * The device core: PROTOCOL.md "Device behaviour (firmware contract)". See rw_core.h.
 *
 * The tests' tests/support/device.py states the same contract in Python; the host tests
 * (rwpend_driver/test/test_firmware.py) run both on the same input and compare every frame.
 */
#include "rw_core.h"

#include <string.h>

#include "rw_version.h"

enum {
    CFG_BAD_COUNTS = -1,
    CFG_BAD_PERIOD = -2,
    CFG_BAD_U_MAX = -3,
    CFG_BAD_WATCHDOG = -4,
};

const char *rw_config_error(int code)
{
    switch (code) {
    case 0:
        return "ok";
    case CFG_BAD_COUNTS:
        return "counts_per_rev must be > 0 for both encoders";
    case CFG_BAD_PERIOD:
        return "sample_period_us must be in 1..65535 (u16 in HELLO_REPLY)";
    case CFG_BAD_U_MAX:
        return "u_max_milli must be in 1..65535 (u16 in HELLO_REPLY)";
    case CFG_BAD_WATCHDOG:
        return "watchdog_ms must be in 2..1000 (SET_WATCHDOG's range)";
    default:
        return "unknown configuration error";
    }
}

static void event(rw_core *c, uint32_t kind, uint32_t now_us, int32_t a, int32_t b)
{
    if (c->on_event) {
        rw_event ev = {kind, c->k, now_us, a, b};
        c->on_event(c->event_ctx, &ev);
    }
}

int rw_core_init(rw_core *c, const rw_config *cfg, rw_event_fn on_event, void *event_ctx)
{
    if (!cfg->counts_per_rev_pendulum || !cfg->counts_per_rev_motor)
        return CFG_BAD_COUNTS;
    if (!cfg->sample_period_us || cfg->sample_period_us > 0xFFFFu)
        return CFG_BAD_PERIOD;
    if (!cfg->u_max_milli || cfg->u_max_milli > 0xFFFFu)
        return CFG_BAD_U_MAX;
    if (cfg->watchdog_ms < RW_WATCHDOG_MIN_MS || cfg->watchdog_ms > RW_WATCHDOG_MAX_MS)
        return CFG_BAD_WATCHDOG;
    /* "Powers up disabled (motor current 0), watchdog 50 ms, encoders zero at power-up" */
    memset(c, 0, sizeof *c);
    c->cfg = *cfg;
    c->on_event = on_event;
    c->event_ctx = event_ctx;
    rw_parser_init(&c->rx, RW_TO_DEVICE);
    c->watchdog_ms = (uint16_t)cfg->watchdog_ms;
    c->cmd_sample = RW_NO_SAMPLE;
    c->applied_sample = RW_NO_SAMPLE;
    return 0;
}

/* ------------------------------------------------------------------ sending */

/* Every frame sent takes the next seq ("seq: u16 frame counter of the sender, +1 per frame
 * sent, wraps"), also one dropped for want of room: the host then sees the gap. */
static size_t send(rw_core *c, uint8_t type, const uint8_t *payload, uint8_t len,
                   uint8_t *out, size_t cap)
{
    size_t n = rw_frame_encode(out, cap, type, c->tx_seq, payload, len);
    c->tx_seq = (uint16_t)(c->tx_seq + 1u);
    c->n.tx_frames++;
    if (!n) {
        c->n.tx_overflow++;
        return 0;
    }
    c->n.tx_bytes += (uint32_t)n;
    return n;
}

/* ACK: u8 request_type, u8 result, u16 request_seq. A result other than ok is a refused frame. */
static size_t ack(rw_core *c, const rw_frame *req, uint8_t result, uint8_t *out, size_t cap)
{
    uint8_t p[RW_ACK_SIZE];
    if (result != RW_R_OK)
        c->n.refused++;
    p[0] = req->type;
    p[1] = result;
    rw_put_u16(p + 2, req->seq);
    return send(c, RW_ACK, p, sizeof p, out, cap);
}

/* HELLO_REPLY: u8 proto_major, u8 proto_minor, u8 fw_major, u8 fw_minor, u8 fw_patch,
 * u8 reserved(0), u32 counts_per_rev_pendulum, u32 counts_per_rev_motor, u16 sample_period_us,
 * u16 u_max_milli, u16 watchdog_ms, u32 serial */
static size_t hello_reply(rw_core *c, uint8_t *out, size_t cap)
{
    uint8_t p[RW_HELLO_REPLY_SIZE];
    p[0] = RW_PROTO_MAJOR;
    p[1] = RW_PROTO_MINOR;
    p[2] = RW_FW_MAJOR;
    p[3] = RW_FW_MINOR;
    p[4] = RW_FW_PATCH;
    p[5] = 0;
    rw_put_u32(p + 6, c->cfg.counts_per_rev_pendulum);
    rw_put_u32(p + 10, c->cfg.counts_per_rev_motor);
    rw_put_u16(p + 14, (uint16_t)c->cfg.sample_period_us);
    rw_put_u16(p + 16, (uint16_t)c->cfg.u_max_milli);
    rw_put_u16(p + 18, c->watchdog_ms);
    rw_put_u32(p + 20, c->cfg.serial);
    return send(c, RW_HELLO_REPLY, p, sizeof p, out, cap);
}

/* ------------------------------------------------------------------ requests */

/* "ENABLE 1 clears WATCHDOG, sets the held command to 0 and restarts the watchdog timer;
 * ENABLE 0 sets the command to 0 and turns the amplifier off." */
static void set_enabled(rw_core *c, uint8_t on, uint32_t now_us)
{
    c->u_milli = 0;
    c->expired = 0;
    c->cmd_sample = RW_NO_SAMPLE;
    c->saturated = 0;
    c->last_command_us = now_us;
    if (on)
        c->tripped = 0;
    if (on != c->enabled) {
        c->enabled = on;
        event(c, on ? RW_EV_ENABLE : RW_EV_DISABLE, now_us, 0, 0);
    }
}

/* COMMAND: u32 sample, i16 u_milli. "(not ACKed; its echo is in SAMPLE): refused and counted
 * in rx_bad if sample is ahead of the last SAMPLE sent or older than the held command's
 * sample; ignored while disabled; else held (zero-order hold) from now on, clamped to
 * +-u_max (SATURATED)." Sample numbers compare modulo 2^32 (the counter wraps). */
static void command(rw_core *c, const rw_frame *f, uint32_t now_us)
{
    uint32_t sample = rw_get_u32(f->payload);
    int32_t u = rw_s16(rw_get_u16(f->payload + 4));
    uint32_t ahead = sample - c->k;
    if (ahead != 0u && ahead < 0x80000000u) {            /* answers a sample not sent yet */
        c->n.refused++;
        return;
    }
    if (!c->enabled) {
        c->n.ignored_commands++;
        return;
    }
    if (c->cmd_sample != RW_NO_SAMPLE && sample - c->cmd_sample >= 0x80000000u) {
        c->n.refused++;                                  /* older than the command held */
        return;
    }
    int32_t lim = (int32_t)c->cfg.u_max_milli;
    c->saturated = (u > lim || u < -lim);
    c->u_milli = (int16_t)(u > lim ? lim : u < -lim ? -lim : u);
    c->cmd_sample = sample;
    c->expired = 0;
    c->last_command_us = now_us;                         /* feeds the watchdog */
    c->fresh = 1;
    c->n.commands++;
}

static size_t handle(rw_core *c, const rw_frame *f, uint32_t now_us, uint8_t *out, size_t cap)
{
    switch (f->type) {
    case RW_COMMAND:
        command(c, f, now_us);
        return 0;
    case RW_HELLO:
        /* "HELLO with proto_major = 1 -> HELLO_REPLY; other major -> ACK result 3" */
        if (f->payload[0] != RW_PROTO_MAJOR)
            return ack(c, f, RW_R_UNSUPPORTED, out, cap);
        return hello_reply(c, out, cap);
    case RW_ENABLE:
        if (f->payload[0] > 1u)
            return ack(c, f, RW_R_BAD_VALUE, out, cap);
        set_enabled(c, f->payload[0], now_us);
        return ack(c, f, RW_R_OK, out, cap);
    case RW_SET_WATCHDOG: {
        uint16_t ms = rw_get_u16(f->payload);
        if (ms < RW_WATCHDOG_MIN_MS || ms > RW_WATCHDOG_MAX_MS)
            return ack(c, f, RW_R_BAD_VALUE, out, cap);  /* "out of range: nothing changes" */
        c->watchdog_ms = ms;
        event(c, RW_EV_WATCHDOG_PERIOD, now_us, ms, 0);
        return ack(c, f, RW_R_OK, out, cap);
    }
    case RW_SET_HOLD: {
        uint16_t n = rw_get_u16(f->payload);
        if (n > RW_HOLD_MAX_SAMPLES)
            return ack(c, f, RW_R_BAD_VALUE, out, cap);  /* "out of range: nothing changes" */
        c->hold_samples = n;
        event(c, RW_EV_HOLD_LIMIT, now_us, n, 0);
        return ack(c, f, RW_R_OK, out, cap);
    }
    case RW_ZERO: {
        uint8_t mask = f->payload[0];
        if (mask == 0u || (mask & ~(RW_ZERO_PENDULUM | RW_ZERO_MOTOR)))
            return ack(c, f, RW_R_BAD_VALUE, out, cap);
        if (c->enabled)                                  /* "ZERO is refused while enabled" */
            return ack(c, f, RW_R_BAD_STATE, out, cap);
        /* the counts read at the last sample instant become zero */
        if (mask & RW_ZERO_PENDULUM)
            c->zero_pendulum = (uint32_t)c->raw_pendulum;
        if (mask & RW_ZERO_MOTOR)
            c->zero_motor = (uint32_t)c->raw_motor;
        c->zeroed = 1;
        event(c, RW_EV_ZERO, now_us, mask, 0);
        return ack(c, f, RW_R_OK, out, cap);
    }
    default:                           /* the parser delivers only the types above */
        return ack(c, f, RW_R_UNSUPPORTED, out, cap);
    }
}

size_t rw_core_receive(rw_core *c, const uint8_t *data, size_t n, uint32_t now_us,
                       uint8_t *out, size_t cap)
{
    size_t used = 0;
    rw_frame f;
    for (size_t i = 0; i < n; i++) {
        rw_parser_put(&c->rx, data[i]);
        while (rw_parser_next(&c->rx, &f))
            used += handle(c, &f, now_us, out + used, cap - used);
    }
    return used;
}

void rw_core_link_lost(rw_core *c)
{
    rw_parser_flush(&c->rx);
}

/* ------------------------------------------------------------------ sample clock */

int32_t rw_core_tick_begin(rw_core *c, uint32_t now_us)
{
    /* "Watchdog: each sample, if enabled and more than watchdog_ms passed since the last valid
     * COMMAND (or ENABLE 1): amplifier off, command 0, WATCHDOG set." */
    uint32_t since = now_us - c->last_command_us;
    if (c->enabled && since > (uint32_t)c->watchdog_ms * 1000u) {
        int32_t before = c->u_milli;
        c->enabled = 0;
        c->tripped = 1;
        c->u_milli = 0;
        c->cmd_sample = RW_NO_SAMPLE;
        c->n.watchdog_trips++;
        event(c, RW_EV_WATCHDOG_TRIP, now_us, since > 0x7FFFFFFFu ? 0x7FFFFFFF : (int32_t)since, before);
    }
    /* "Hold limit: each sample, if enabled, a hold limit is set and the held command is not 0
     * and answers a sample more than max_age samples before the one this period ends at (k+1):
     * command 0 until the next valid COMMAND; the SAMPLE says no command held." */
    if (c->enabled && c->hold_samples && c->u_milli != 0 && c->cmd_sample != RW_NO_SAMPLE
        && c->k + 1u - c->cmd_sample > (uint32_t)c->hold_samples) {
        int32_t before = c->u_milli;
        c->u_milli = 0;
        c->saturated = 0;
        c->expired = 1;
        c->n.hold_expired++;
        event(c, RW_EV_HOLD_EXPIRED, now_us, (int32_t)(c->k + 1u - c->cmd_sample), before);
    }
    /* "apply held command for the period" (0 when disabled) */
    c->applied_milli = c->enabled ? c->u_milli : 0;
    c->applied_sample = c->enabled && !c->expired ? c->cmd_sample : RW_NO_SAMPLE;
    return c->applied_milli;
}

static uint16_t status(const rw_core *c, uint8_t fast)
{
    uint16_t s = 0;
    if (c->enabled)
        s |= RW_ST_ENABLED;
    if (c->tripped)
        s |= RW_ST_WATCHDOG;
    if (fast)
        s |= RW_ST_OVERSPEED;
    if (c->fresh)
        s |= RW_ST_CMD_FRESH;
    if (c->saturated)
        s |= RW_ST_SATURATED;
    if (c->zeroed)
        s |= RW_ST_ZEROED;
    return s;
}

/* |rotor speed relative to the pendulum| from the motor counter (the rotor relative to the
 * pendulum) over the period just ended, against the back-EMF limit in counts per period. */
static uint8_t overspeed(const rw_core *c, int32_t motor_counts)
{
    if (!c->have_counts || !c->cfg.overspeed_counts)
        return 0;
    int32_t d = rw_s32((uint32_t)motor_counts - (uint32_t)c->raw_motor);
    uint32_t mag = d < 0 ? 0u - (uint32_t)d : (uint32_t)d;
    return mag > c->cfg.overspeed_counts;
}

/* SAMPLE: u32 sample, u32 time_us, i32 pendulum_counts, i32 motor_counts, u16 status,
 * i16 u_applied_milli, u32 cmd_sample, u16 rx_bad */
size_t rw_core_tick_end(rw_core *c, uint32_t now_us, int32_t pendulum_counts,
                        int32_t motor_counts, uint8_t *out, size_t cap)
{
    uint8_t p[RW_SAMPLE_SIZE];
    uint8_t fast = overspeed(c, motor_counts);
    c->overspeed = fast;
    c->raw_pendulum = pendulum_counts;
    c->raw_motor = motor_counts;
    c->have_counts = 1;
    c->k++;                                              /* wraps at 2^32 */
    c->n.samples++;
    uint16_t st = status(c, fast);
    c->fresh = 0;                                        /* "since the previous sample" */
    rw_put_u32(p, c->k);
    rw_put_u32(p + 4, now_us);                           /* "device clock at the sample" */
    rw_put_u32(p + 8, (uint32_t)pendulum_counts - c->zero_pendulum);
    rw_put_u32(p + 12, (uint32_t)motor_counts - c->zero_motor);
    rw_put_u16(p + 16, st);
    rw_put_u16(p + 18, (uint16_t)c->applied_milli);
    rw_put_u32(p + 20, c->applied_sample);
    rw_put_u16(p + 24, (uint16_t)(rw_rx_errors(&c->rx.st) + c->n.refused));  /* u16, wraps */
    return send(c, RW_SAMPLE, p, sizeof p, out, cap);
}

rw_drive rw_core_drive(const rw_core *c)
{
    rw_drive d = {0, 0, 0};
    if (c->enabled) {
        d.amplifier_on = 1;
        d.reverse = c->u_milli < 0;
        d.magnitude_milli = (uint16_t)(c->u_milli < 0 ? -(int32_t)c->u_milli : c->u_milli);
    }
    return d;
}

int32_t rw_counter_extend16(int32_t prev, uint16_t raw)
{
    int16_t step = rw_s16((uint16_t)(raw - (uint16_t)(uint32_t)prev));
    return rw_s32((uint32_t)prev + (uint32_t)(int32_t)step);
}

void rw_core_set_sample(rw_core *c, uint32_t k)
{
    c->k = k;
}

void rw_core_snapshot(const rw_core *c, rw_snapshot *s)
{
    memset(s, 0, sizeof *s);
    s->sample = c->k;
    s->enabled = c->enabled;
    s->tripped = c->tripped;
    s->u_milli = c->enabled ? c->u_milli : 0;
    s->u_applied_milli = c->applied_milli;
    s->cmd_sample = c->cmd_sample;
    s->watchdog_ms = c->watchdog_ms;
    s->pendulum_counts = rw_s32((uint32_t)c->raw_pendulum - c->zero_pendulum);
    s->motor_counts = rw_s32((uint32_t)c->raw_motor - c->zero_motor);
    s->status = status(c, c->overspeed);
    s->rx_bad = (uint16_t)(rw_rx_errors(&c->rx.st) + c->n.refused);
    s->commands = c->n.commands;
    s->ignored_commands = c->n.ignored_commands;
    s->refused = c->n.refused;
    s->watchdog_trips = c->n.watchdog_trips;
    s->hold_samples = c->hold_samples;
    s->hold_expired = c->n.hold_expired;
    s->samples = c->n.samples;
    s->tx_frames = c->n.tx_frames;
    s->tx_bytes = c->n.tx_bytes;
    s->tx_overflow = c->n.tx_overflow;
    s->tx_seq = c->tx_seq;
    s->rx_frames = c->rx.st.frames;
    s->rx_bad_crc = c->rx.st.bad_crc;
    s->rx_bad_length = c->rx.st.bad_length;
    s->rx_truncated = c->rx.st.truncated;
    s->rx_unknown_type = c->rx.st.unknown_type;
    s->rx_garbage_bytes = c->rx.st.garbage_bytes;
    s->rx_bytes = c->rx.st.bytes;
}

#define RW_X_NAME(ctype, code, name) #code " " #name ","

const char *rw_snapshot_layout(void)
{
    return RW_SNAPSHOT_FIELDS(RW_X_NAME);
}

const char *rw_config_layout(void)
{
    return RW_CONFIG_FIELDS(RW_X_NAME);
}

#undef RW_X_NAME

size_t rw_core_size(void)
{
    return sizeof(rw_core);
}

size_t rw_snapshot_size(void)
{
    return sizeof(rw_snapshot);
}

size_t rw_config_size(void)
{
    return sizeof(rw_config);
}

const char *rw_fw_version(void)
{
    return RW_FW_VERSION_STRING;
}
