/**
 * @file main.c
 * @brief The firmware core on an ATmega2560 at 16 MHz: USART0 by interrupt, a timer
 *        tick, PWM and direction outputs to the motor drivers, encoder counts from an
 *        external quadrature decoder (docs/firmware.md, "Processor in the loop").
 *
 * Peripherals (ATmega640/1280/2560 datasheet):
 *
 *   - USART0 (PE0 RXD0, PE1 TXD0): 115200 8N1 with U2X0 (UBRR0 = 16: 117,647 baud, +2.1 %);
 *     the RX complete interrupt fills a 256-byte ring, the data-register-empty interrupt
 *     empties a 256-byte transmit ring of whole frames; a STOP_ACK drops the sensor
 *     samples still queued (below). A frame that does not fit is dropped whole and
 *     counted; fw_hal_write never blocks.
 *   - Timer1, CTC on OCR1A, prescaler 64 (4 us): the control tick, FW_AVR_TICK_US (10 ms by
 *     default: fw_tick's worst case on this 8-bit core is several milliseconds, so a 1 ms
 *     tick cannot hold; the braking law is computed for the tick it is given), and the
 *     64-bit microsecond clock (ticks * FW_AVR_TICK_US + TCNT1 * 4).
 *   - Timer3, prescaler 8: fw_tick's duration in CPU cycles (8-cycle resolution).
 *   - Timer4, fast PWM with TOP = ICR4 = 15999 (1 kHz): OC4A (PH3) left motor, OC4B (PH4)
 *     right; PH5 and PH6 their direction (1: reverse). Duty 100 % is
 *     FW_AVR_PWM_FULL_SCALE_UM_S of wheel surface speed.
 *   - Encoders: the count registers of an external quadrature decoder and its error
 *     line (pil_sensors, pil_port.h), which the simavr harness fills from the twin; a board
 *     reads its decoder (an LS7366R over SPI, say) in sensors_read instead. The IMU and the
 *     pose fix come the same way.
 *   - The boot nonce: the low bits of Timer3 at the first HELLO-independent point
 *     (the reset's time is not repeatable on hardware; under simavr it is, so the
 *     harness seeds it through GPIOR1/GPIOR2, which a board does not need).
 *
 * The core runs in the main loop only (never in an ISR); the CPU sleeps (idle) when there
 * is nothing to do.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "../fw.h"
#include "../port_pil/pil_port.h"

#ifndef FW_AVR_TICK_US
#define FW_AVR_TICK_US 10000u
#endif
#ifndef FW_AVR_PWM_FULL_SCALE_UM_S
#define FW_AVR_PWM_FULL_SCALE_UM_S 400000L
#endif
#define PWM_TOP 15999u
#define TIMER1_US_PER_COUNT 4u
#define RX_RING 256u
#define TX_RING 256u

static fw_t controller;
static fw_config_t config;
volatile pil_sensors_t pil_sensors;
static pil_sensors_t sensors; /* this tick's copy */
static uint8_t pose_seq_seen;
static uint8_t encoder_error_seen;

static volatile uint8_t rx_ring[RX_RING];
static volatile uint8_t rx_head; /* ISR */
static volatile uint8_t rx_tail; /* main loop */
/* The transmit ring holds frames as [length][bytes], sent in order. When the core answers
 * a STOP (STOP_ACK), the sensor samples still queued (ENCODERS, WHEEL_SPEEDS, IMU, POSE:
 * taken before the STOP, superseded by the next ones) are dropped, so that STOP_ACK does
 * not wait behind a ring of them at 115200 baud and no sample from before the STOP
 * reaches the host after its STOP_ACK; every other frame keeps its place. */
static volatile uint8_t tx_ring[TX_RING];
static volatile uint8_t tx_head; /* main loop */
static volatile uint8_t tx_tail; /* ISR */
static volatile uint8_t tx_left; /* bytes left of the frame being sent (ISR) */
static volatile uint32_t grid_ticks; /* Timer1 compares */
static volatile uint16_t rx_stamp;   /* TCNT3 when the newest byte came in (ISR) */
static uint16_t rx_stamp_fed;        /* rx_stamp of the bytes being handed to the core */

/* ------------------------------------------------------------------ clock */

static uint64_t now_us(void)
{
    uint32_t ticks;
    uint16_t counts;
    uint8_t sreg = SREG;
    cli();
    ticks = grid_ticks;
    counts = TCNT1;
    if ((TIFR1 & (1 << OCF1A)) != 0u && counts < (uint16_t)(OCR1A / 2u)) {
        ticks++; /* the compare happened, its interrupt is still pending */
    }
    SREG = sreg;
    return (uint64_t)ticks * FW_AVR_TICK_US + (uint64_t)counts * TIMER1_US_PER_COUNT;
}

/* ------------------------------------------------------------------ interrupts */

ISR(USART0_RX_vect)
{
    const uint8_t status = UCSR0A;
    rx_stamp = TCNT3;
    const uint8_t b = UDR0;
    const uint8_t next = (uint8_t)(rx_head + 1u);
    if ((status & ((1 << DOR0) | (1 << FE0))) != 0u || next == rx_tail) {
        pil_stats.rx_overflows++;
        return;
    }
    rx_ring[rx_head] = b;
    rx_head = next;
}

ISR(USART0_UDRE_vect)
{
    if (tx_left == 0u) {
        if (tx_tail == tx_head) {
            UCSR0B &= (uint8_t)~(1 << UDRIE0);
            return;
        }
        tx_left = tx_ring[tx_tail];
        tx_tail = (uint8_t)(tx_tail + 1u);
    }
    UDR0 = tx_ring[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1u);
    tx_left--;
}

ISR(TIMER1_COMPA_vect) { grid_ticks++; }

/* ------------------------------------------------------------------ HAL */

/** The message id of a frame as fw_hal_write gets it: 0x00, COBS(id, seq, ...), 0x00. */
static uint8_t frame_id(const volatile uint8_t *ring, uint8_t at)
{
    const uint8_t code = ring[(uint8_t)(at + 1u)];
    return code == 1u ? 0u : ring[(uint8_t)(at + 2u)];
}

static int is_sample(uint8_t id)
{
    return id == RP_MSG_ENCODERS || id == RP_MSG_WHEEL_SPEEDS || id == RP_MSG_IMU ||
           id == RP_MSG_POSE;
}

/** Drop the queued samples not yet started (interrupts off: the ISR takes from tail). */
static void drop_queued_samples(void)
{
    uint8_t keep[TX_RING];
    uint16_t kept = 0u;
    uint8_t at;
    uint8_t sreg = SREG;
    cli();
    at = tx_tail;
    if (tx_left != 0u) {
        at = (uint8_t)(at + tx_left); /* the frame on the wire finishes */
    }
    {
        const uint8_t start = at;
        while (at != tx_head) {
            const uint8_t len = tx_ring[at];
            uint8_t i;
            if (!is_sample(frame_id(tx_ring, (uint8_t)(at + 1u)))) {
                for (i = 0u; i <= len; i++) {
                    keep[kept++] = tx_ring[(uint8_t)(at + i)];
                }
            }
            at = (uint8_t)(at + len + 1u);
        }
        at = start;
    }
    {
        uint16_t i;
        for (i = 0u; i < kept; i++) {
            tx_ring[(uint8_t)(at + i)] = keep[i];
        }
        tx_head = (uint8_t)(at + kept);
    }
    SREG = sreg;
}

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    size_t i;
    uint8_t used;
    uint8_t sreg;
    pil_note_answer(bytes, n, (uint32_t)(uint16_t)(TCNT3 - rx_stamp_fed) * 8u);
    if (n >= 3u && (bytes[1] == 1u ? 0u : bytes[2]) == RP_MSG_STOP_ACK) {
        drop_queued_samples();
    }
    sreg = SREG;
    cli();
    used = (uint8_t)(tx_head - tx_tail);
    if ((size_t)used + n + 1u >= TX_RING || n == 0u || n > 255u) {
        pil_stats.tx_drops++;
        SREG = sreg;
        return;
    }
    tx_ring[tx_head] = (uint8_t)n;
    tx_head = (uint8_t)(tx_head + 1u);
    for (i = 0u; i < n; i++) {
        tx_ring[tx_head] = bytes[i];
        tx_head = (uint8_t)(tx_head + 1u);
    }
    UCSR0B |= (uint8_t)(1 << UDRIE0);
    SREG = sreg;
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    (void)can_id;
    (void)data;
    (void)len;
}

static uint16_t pwm_duty(int32_t um_s)
{
    uint32_t mag = (uint32_t)(um_s < 0 ? -(int64_t)um_s : um_s);
    uint32_t duty = (uint32_t)(((uint64_t)mag * (PWM_TOP + 1u) + FW_AVR_PWM_FULL_SCALE_UM_S / 2) /
                               (uint64_t)FW_AVR_PWM_FULL_SCALE_UM_S);
    return (uint16_t)(duty > PWM_TOP ? PWM_TOP : duty);
}

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    uint8_t dir = PORTH & (uint8_t)~((1 << PH5) | (1 << PH6));
    if (left_um_s < 0) {
        dir |= (uint8_t)(1 << PH5);
    }
    if (right_um_s < 0) {
        dir |= (uint8_t)(1 << PH6);
    }
    PORTH = dir;
    OCR4A = pwm_duty(left_um_s);
    OCR4B = pwm_duty(right_um_s);
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = sensors.enc[0];
    *right = sensors.enc[1];
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = sensors.speed_um_s[0];
    *right_um_s = sensors.speed_um_s[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    if (sensors.imu_valid == 0u) {
        return 0;
    }
    out->yaw_rate_mrad_s = sensors.imu[0];
    out->accel_x_mm_s2 = sensors.imu[1];
    out->accel_y_mm_s2 = sensors.imu[2];
    return 1;
}

void fw_hal_pose_sample(void) {} /* the tracking system samples on its own */

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    if (sensors.pose_seq == pose_seq_seen) {
        return 0;
    }
    pose_seq_seen = sensors.pose_seq;
    out->x_mm = sensors.pose_x_mm;
    out->y_mm = sensors.pose_y_mm;
    out->yaw_ddeg = sensors.pose_yaw_ddeg;
    out->sigma_cm = sensors.pose_sigma_cm;
    out->taken_us = controller.now_us > sensors.pose_age_us
                        ? controller.now_us - sensors.pose_age_us
                        : 0u;
    return 1;
}

uint16_t fw_hal_boot_nonce(void)
{
    /* On a board: ADC noise of a floating pin. Here the harness's seed (GPIOR1/2) mixed
     * with the timer, so that each reset gets a new nonce and a seed repeats them. */
    return (uint16_t)(((uint16_t)GPIOR2 << 8 | GPIOR1) ^ TCNT3 ^ (uint16_t)grid_ticks);
}

/** This tick's sensors, and the encoder error line into the core's ENCODER fault. */
static void sensors_read(uint64_t now)
{
    pil_sensors_copy(&sensors, &pil_sensors);
    if (sensors.encoder_error != 0u && encoder_error_seen == 0u) {
        fw_raise_fault(&controller, now, (uint8_t)RP_FAULT_CODE_ENCODER, 0u, true);
    } else if (sensors.encoder_error == 0u && encoder_error_seen != 0u) {
        fw_clear_fault(&controller, (uint8_t)RP_FAULT_CODE_ENCODER);
    }
    encoder_error_seen = sensors.encoder_error;
}

/* ------------------------------------------------------------------ set-up and loop */

static void hardware_init(void)
{
    /* USART0 */
    UBRR0 = 16u;
    UCSR0A = (uint8_t)(1 << U2X0);
    UCSR0C = (uint8_t)((1 << UCSZ01) | (1 << UCSZ00));
    UCSR0B = (uint8_t)((1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0));
    /* Timer1: the tick, CTC, prescaler 64 */
    TCCR1A = 0u;
    TCCR1B = (uint8_t)((1 << WGM12) | (1 << CS11) | (1 << CS10));
    OCR1A = (uint16_t)(FW_AVR_TICK_US / TIMER1_US_PER_COUNT - 1u);
    TIMSK1 = (uint8_t)(1 << OCIE1A);
    /* Timer3: free-running, prescaler 8, for fw_tick's cost */
    TCCR3A = 0u;
    TCCR3B = (uint8_t)(1 << CS31);
    pil_stats.tick_unit_hz = 16000000u;
    /* Timer4: fast PWM, TOP = ICR4, non-inverting on OC4A and OC4B, prescaler 1 */
    DDRH |= (uint8_t)((1 << PH3) | (1 << PH4) | (1 << PH5) | (1 << PH6));
    TCCR4A = (uint8_t)((1 << COM4A1) | (1 << COM4B1) | (1 << WGM41));
    TCCR4B = (uint8_t)((1 << WGM43) | (1 << WGM42) | (1 << CS40));
    ICR4 = PWM_TOP;
    OCR4A = 0u;
    OCR4B = 0u;
    set_sleep_mode(SLEEP_MODE_IDLE);
}

static void drain_rx(void)
{
    uint8_t chunk[32];
    uint8_t n = 0u;
    uint8_t sreg = SREG;
    cli();
    rx_stamp_fed = rx_stamp;
    SREG = sreg;
    while (rx_tail != rx_head) {
        chunk[n++] = rx_ring[rx_tail];
        rx_tail = (uint8_t)(rx_tail + 1u);
        if (n == sizeof chunk) {
            fw_on_bytes(&controller, now_us(), chunk, n);
            n = 0u;
        }
    }
    if (n != 0u) {
        fw_on_bytes(&controller, now_us(), chunk, n);
    }
}

int main(void)
{
    uint32_t done_ticks = 0u;
    fw_default_config(&config);
    config.tick_us = FW_AVR_TICK_US;
    hardware_init();
    sei();
    pil_sensors_copy(&sensors, &pil_sensors);
    pose_seq_seen = sensors.pose_seq;
    if (fw_init(&controller, &config, now_us()) != FW_OK) {
        fw_hal_set_wheels(0, 0);
        for (;;) {
            sleep_mode(); /* a configuration the core refuses: wheels at zero */
        }
    }
    for (;;) {
        uint32_t due;
        drain_rx();
        cli();
        due = grid_ticks;
        sei();
        if (due != done_ticks) {
            uint16_t start;
            uint32_t spent;
            uint64_t now;
            if (due - done_ticks > 1u) {
                pil_stats.late_ticks += due - done_ticks - 1u;
            }
            done_ticks = due;
            now = now_us();
            start = TCNT3;
            sensors_read(now);
            fw_tick(&controller, now);
            spent = (uint32_t)(uint16_t)(TCNT3 - start) * 8u;
            pil_stats.ticks++;
            pil_stats.tick_last = spent;
            if (spent > pil_stats.tick_max) {
                pil_stats.tick_max = spent;
            }
            pil_view_update(&controller, sensors.speed_um_s[0], sensors.speed_um_s[1]);
        }
        cli();
        if (rx_tail == rx_head && grid_ticks == done_ticks) {
            sleep_enable();
            sei();
            sleep_cpu(); /* the instruction after sei runs first: no lost wake-up */
            sleep_disable();
        }
        sei();
    }
}
