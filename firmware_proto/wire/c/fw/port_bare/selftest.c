/**
 * @file selftest.c
 * @brief The firmware core's self-test on the target: a scripted host and an ideal plant
 *        behind the HAL, run on an ATmega2560 under simavr, on a Cortex-M0 (the BBC
 *        micro:bit) under qemu-system-arm with semihosting for its output
 *        (tests/firmware_proto/test_fw.py), or on the host.
 *
 * The script: HELLO (IDENT, session open); a 0.1 m FWD step run to COMPLETED with
 * travel 2300; a long step stopped half-way: STOP_ACK first, the targets zero on return,
 * STOPPED once at rest, MOTION refused STOP_LATCHED, CLEAR_STOP answered CLEARED; then
 * CAN frames (another node's, our own kind echoed, a bad one, a broadcast) received as
 * the Python CAN endpoint takes them; then a 0.1 m step whose encoder counters wrap
 * half-way (fw_hal.h), run to COMPLETED with travel 2300 after 0.1 m. It
 * prints one line per check and `selftest: ok` (or FAILED), then the cost of fw_tick:
 * on AVR in CPU cycles from Timer1 (prescaler 8: 8-cycle resolution, right while a tick
 * takes under 524,288 cycles); on the micro:bit in SysTick counts at its 16 MHz core
 * clock, which under `qemu-system-arm -icount shift=6` (64 ns per instruction) are
 * 1.024 counts per instruction executed; on the host nothing.
 */
#include <stdio.h>

#include "../fw.h"

#ifdef __AVR__
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/interrupt.h>

static int uart_putchar(char ch, FILE *stream)
{
    (void)stream;
    while ((UCSR0A & (1 << UDRE0)) == 0) {
    }
    UDR0 = (uint8_t)ch;
    return 0;
}

static FILE uart_out = FDEV_SETUP_STREAM(uart_putchar, NULL, _FDEV_SETUP_WRITE);
#endif

#ifdef FW_SELFTEST_MICROBIT
/* Start-up for the micro:bit image (microbit.ld): the vector table, .data copied from
 * flash, .bss zeroed, then main; output and exit through semihosting (newlib's rdimon). */
#include <stdlib.h>

int main(void);
void Reset_Handler(void);
void Fault_Handler(void);
extern void initialise_monitor_handles(void);
extern uint32_t __data_load, __data_start, __data_end, __bss_start__, __bss_end__;
extern void __stack_top(void); /* a linker symbol, declared so that it fits the table */

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    __stack_top, Reset_Handler, Fault_Handler, Fault_Handler,
};

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

void Fault_Handler(void)
{
    exit(99);
}

void Reset_Handler(void)
{
    uint32_t *src = &__data_load;
    uint32_t *dst;
    for (dst = &__data_start; dst < &__data_end;) {
        *dst++ = *src++;
    }
    for (dst = &__bss_start__; dst < &__bss_end__;) {
        *dst++ = 0u;
    }
    initialise_monitor_handles();
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 5u; /* enabled, core clock, no interrupt */
    exit(main());
}
#endif

#ifdef __AVR__
#define COUNTER "cycles"
#else
#define COUNTER "SysTick counts"
#endif

/* ------------------------------------------------------------------ plant and HAL */

static int32_t wheel_cmd[2], enc[2];
static int32_t enc_um[2];
static uint32_t enc_base[2]; /* the counter's value when enc_um was 0 */
static rp_decoder_t out_dec;
static rp_msg_t last[16];
static uint8_t n_last;

void fw_hal_set_wheels(int32_t l, int32_t r)
{
    wheel_cmd[0] = l;
    wheel_cmd[1] = r;
}

void fw_hal_read_encoders(int32_t *l, int32_t *r)
{
    *l = enc[0];
    *r = enc[1];
}

void fw_hal_read_wheel_speeds(int32_t *l, int32_t *r)
{
    *l = wheel_cmd[0];
    *r = wheel_cmd[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    (void)out;
    return 0;
}

void fw_hal_pose_sample(void) {}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    (void)out;
    return 0;
}

uint16_t fw_hal_boot_nonce(void) { return 0x5EEDu; }

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    rp_frame_t f;
    while (rp_decoder_feed(&out_dec, &bytes, &n, &f)) {
        if (n_last < 16u) {
            last[n_last++] = f.msg;
        }
    }
}

void fw_hal_can_send(uint16_t id, const uint8_t *d, uint8_t len)
{
    (void)id;
    (void)d;
    (void)len;
}

/* v as a two's-complement int32 (the counter wraps modulo 2^32). */
static int32_t as_i32(uint32_t v)
{
    return v < 0x80000000u ? (int32_t)v : -(int32_t)(0xFFFFFFFFu - v) - 1;
}

static uint32_t units(uint8_t side)
{
    return (uint32_t)(int32_t)((int64_t)enc_um[side] * 23 / 1000);
}

/* Integrates the commands exactly (um per 1 ms tick), 23 units per mm. */
static void plant_step(void)
{
    uint8_t side;
    for (side = 0u; side < 2u; side++) {
        enc_um[side] += wheel_cmd[side] / 1000;
        enc[side] = as_i32(enc_base[side] + units(side));
    }
}

/* ------------------------------------------------------------------ the script */

static fw_t c;
static uint64_t now;
static uint32_t tick_cycles_max, tick_cycles_sum, tick_count;

static void tick(void)
{
    now += c.cfg.tick_us;
#ifdef __AVR__
    {
        uint16_t t0, t1;
        uint32_t cycles;
        t0 = TCNT1;
        fw_tick(&c, now);
        t1 = TCNT1;
        /* Modulo 2^16 counts: right while fw_tick takes under 524,288 cycles. */
        cycles = (uint32_t)(uint16_t)(t1 - t0) * 8u;
        tick_cycles_sum += cycles;
        if (cycles > tick_cycles_max) {
            tick_cycles_max = cycles;
        }
        tick_count++;
    }
#elif defined(FW_SELFTEST_MICROBIT)
    {
        /* SysTick counts down from 2^24 - 1 at the core clock. */
        const uint32_t t0 = SYST_CVR;
        uint32_t cycles;
        fw_tick(&c, now);
        cycles = (t0 - SYST_CVR) & 0xFFFFFFu;
        tick_cycles_sum += cycles;
        if (cycles > tick_cycles_max) {
            tick_cycles_max = cycles;
        }
        tick_count++;
    }
#else
    fw_tick(&c, now);
#endif
    plant_step();
}

static void send(const rp_msg_t *m)
{
    uint8_t wire[RP_MAX_WIRE_BYTES];
    const int n = rp_encode_message(m, 0u, false, wire, sizeof wire);
    n_last = 0u;
    if (n > 0) {
        fw_on_bytes(&c, now, wire, (size_t)n);
    }
}

static void heartbeat(void)
{
    rp_msg_t m;
    m.id = RP_MSG_HOST_HEARTBEAT;
    m.body.host_heartbeat.counter = 1u;
    send(&m);
}

static int find(uint8_t id)
{
    uint8_t i;
    for (i = 0u; i < n_last; i++) {
        if (last[i].id == id) {
            return (int)i;
        }
    }
    return -1;
}

/** Ticks (feeding the watchdog) until a frame with id comes; its index in last, or -1. */
static int run_until(uint8_t id, uint16_t max_ticks)
{
    uint16_t k;
    for (k = 0u; k < max_ticks; k++) {
        int at;
        if (k % 50u == 0u) {
            heartbeat();
        }
        n_last = 0u;
        tick();
        at = find(id);
        if (at >= 0) {
            return at;
        }
    }
    return -1;
}

static int failures;

static void check(int ok, const char *what)
{
    printf("%s %s\n", ok ? "pass" : "FAIL", what);
    if (!ok) {
        failures++;
    }
}

static void motion(uint16_t seq, uint16_t distance)
{
    rp_msg_t m;
    m.id = RP_MSG_MOTION;
    m.body.motion.seq = seq;
    m.body.motion.command = RP_COMMAND_FWD;
    m.body.motion.speed = 40u;
    m.body.motion.distance = distance;
    send(&m);
}

int main(void)
{
    fw_config_t cfg;
    rp_msg_t m;
    int at;
#ifdef __AVR__
    stdout = &uart_out;
    UCSR0B = (uint8_t)(1 << TXEN0);
    TCCR1A = 0u;
    TCCR1B = (uint8_t)(1 << CS11); /* Timer1 counts CPU cycles / 8 */
#endif
    rp_decoder_init(&out_dec);
    fw_default_config(&cfg);
    check(fw_init(&c, &cfg, now) == FW_OK, "the default configuration is taken");
    check(n_last == 1u && last[0].id == RP_MSG_IDENT, "IDENT at boot");

    m.id = RP_MSG_HELLO;
    m.body.hello.protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
    m.body.hello.schema_hash = (uint16_t)RP_SCHEMA_HASH;
    send(&m);
    check(n_last == 1u && last[0].id == RP_MSG_IDENT && c.handshake_ok, "HELLO opens a session");

    motion(1u, 2300u);
    check(n_last == 1u && last[0].body.ack.result == RP_ACK_RESULT_ACCEPTED, "MOTION accepted");
    at = run_until(RP_MSG_STATUS, 10u);
    check(at >= 0 && last[at].body.status.state == RP_STEP_STATE_STARTED, "step started");
    at = run_until(RP_MSG_STATUS, 3000u);
    check(at >= 0 && last[at].body.status.state == RP_STEP_STATE_COMPLETED &&
              last[at].body.status.travel == 2300u,
          "step completed, travel 2300");

    motion(2u, 30000u);
    run_until(RP_MSG_HEARTBEAT, 400u);
    check(c.setpoint[0] > 0 && c.state == RP_CONTROLLER_STATE_EXECUTING, "driving");
    m.id = RP_MSG_STOP;
    m.body.stop.stop_id = 7u;
    m.body.stop.source = 4u;
    send(&m);
    check(n_last >= 2u && last[0].id == RP_MSG_STOP_ACK && last[1].id == RP_MSG_STATUS &&
              last[1].body.status.reason == RP_ABORT_REASON_STOP,
          "STOP_ACK first, then the step aborted");
    const uint8_t gen = last[0].body.stop_ack.latch_gen; /* the latch CLEAR_STOP names */
    check(c.setpoint[0] == 0 && c.setpoint[1] == 0 && c.latch == FW_LATCH_STOP,
          "targets zero and latched on return");
    at = run_until(RP_MSG_STOPPED, 1000u);
    check(at >= 0 && last[at].body.stopped.stop_id == 7u, "STOPPED at rest");
    motion(3u, 100u);
    check(n_last == 1u && last[0].body.ack.result == RP_ACK_RESULT_STOP_LATCHED,
          "MOTION refused while latched");
    m.id = RP_MSG_CLEAR_STOP;
    m.body.clear_stop.stop_id = 8u;
    m.body.clear_stop.latch_gen = gen;
    send(&m);
    check(n_last == 1u && last[0].body.clear_ack.result == RP_CLEAR_RESULT_CLEARED,
          "CLEAR_STOP releases the latch");

    {
        /* CAN receive: errors count whoever they were for; foreign frames do not. */
        const uint8_t hb[2] = {1u, 0u};
        const uint8_t ack[5] = {0u, 0u, 0u, 0u, 0u};
        const uint32_t before = c.rx_errors;
        fw_on_can(&c, now, RP_MSG_HOST_HEARTBEAT << 4 | 2u, false, false, hb, 2u);
        check(c.rx_errors == before, "CAN: another node's frame ignored");
        fw_on_can(&c, now, RP_MSG_ACK << 4 | 1u, false, false, ack, 5u);
        check(c.rx_errors == before, "CAN: our own kind echoed back ignored");
        fw_on_can(&c, now, RP_MSG_HOST_HEARTBEAT << 4 | 2u, false, false, hb, 1u);
        check(c.rx_errors == before + 1u, "CAN: a bad frame counted, whoever it was for");
        n_last = 0u;
        fw_on_can(&c, now, RP_MSG_HOST_HEARTBEAT << 4 | 0u, false, false, hb, 2u);
        check(c.rx_errors == before + 1u && c.last_rx_us == now, "CAN: a broadcast taken");
    }

    {
        /* Motor frame, forward: the left counter (polarity -1) counts down through
         * INT32_MIN and the right one up through INT32_MAX, 0.05 m into the step. */
        const int32_t left_um = enc_um[0], right_um = enc_um[1];
        enc_base[0] = 0x80000000u + 1150u - units(0);
        enc_base[1] = 0x7FFFFFFFu - 1150u - units(1);
        plant_step();
        motion(4u, 2300u);
        at = run_until(RP_MSG_STATUS, 10u);
        check(at >= 0 && last[at].body.status.state == RP_STEP_STATE_STARTED, "wrap: started");
        at = run_until(RP_MSG_STATUS, 3000u);
        check(at >= 0 && last[at].body.status.state == RP_STEP_STATE_COMPLETED &&
                  last[at].body.status.travel == 2300u,
              "a step across the encoder wrap completed, travel 2300");
        check(left_um - enc_um[0] > 99000 && left_um - enc_um[0] < 101000 &&
                  enc_um[1] - right_um > 99000 && enc_um[1] - right_um < 101000 && enc[0] > 0 &&
                  enc[1] < 0,
              "both counters wrapped; both wheels drove 0.1 m");
    }

    printf("selftest: %s\n", failures == 0 ? "ok" : "FAILED");
    if (tick_count > 0u) {
        printf("fw_tick " COUNTER ": avg %lu max %lu over %lu ticks\n",
               (unsigned long)(tick_cycles_sum / tick_count), (unsigned long)tick_cycles_max,
               (unsigned long)tick_count);
    }
#ifdef __AVR__
    cli();
    sleep_cpu(); /* simavr stops here */
#endif
    return failures;
}
