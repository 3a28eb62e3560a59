/**
 * @file main.c
 * @brief The firmware core on an nRF51822 (the BBC micro:bit): UART by interrupt, a 1 ms
 *        tick on a fixed timer grid, a 64-bit microsecond clock, the RNG boot nonce; with
 *        FW_PIL, a kinematic wheel and encoder model inside the image and the runner's
 *        fault hooks (docs/firmware.md, "Processor in the loop").
 *
 * Peripherals (nRF51 Series Reference Manual v3.0):
 *
 *   - UART0 (0x40002000, IRQ 2): 115200 8N1; RXDRDY and TXDRDY interrupts. The ISR moves
 *     received bytes into a 256-byte ring and feeds the transmitter from a 512-byte ring;
 *     the main loop hands received bytes to fw_on_bytes. A frame that does not fit the
 *     transmit ring is dropped whole and counted (fw_hal_write never blocks).
 *   - TIMER0 (0x40008000, IRQ 8): 1 MHz, CC[0] = tick_us with the COMPARE0_CLEAR short:
 *     a fixed grid that is never re-armed by software (under qemu, a TIMER0 compare that
 *     the firmware re-arms each tick was seen never to wake WFI; the fixed grid does).
 *   - TIMER1 (0x40009000): 1 MHz, 32 bits, free-running: the clock, read by CAPTURE[0]
 *     and extended to 64 bits in software.
 *   - TIMER2 (0x4000A000): 16 MHz, 32 bits, free-running: fw_tick's duration in CPU
 *     clock cycles (pil_stats.tick_max; under qemu without -icount, host time).
 *   - RNG (0x4000D000): two bytes for the boot nonce.
 *
 * The core runs in the main loop only (never in an ISR), so it is never re-entered; the
 * CPU sleeps in WFI when there is nothing to do.
 */
#include "../fw.h"
#include "../port_pil/pil_port.h"
#ifdef FW_PIL
#include "../port_pil/pil_plant.h"
#endif

#define REG(addr) (*(volatile uint32_t *)(addr))

#define UART_BASE 0x40002000u
#define UART_STARTRX REG(UART_BASE + 0x000u)
#define UART_STARTTX REG(UART_BASE + 0x008u)
#define UART_RXDRDY REG(UART_BASE + 0x108u)
#define UART_TXDRDY REG(UART_BASE + 0x11Cu)
#define UART_ERROR REG(UART_BASE + 0x124u)
#define UART_INTENSET REG(UART_BASE + 0x304u)
#define UART_ERRORSRC REG(UART_BASE + 0x480u)
#define UART_ENABLE REG(UART_BASE + 0x500u)
#define UART_PSELTXD REG(UART_BASE + 0x50Cu)
#define UART_PSELRXD REG(UART_BASE + 0x514u)
#define UART_RXD REG(UART_BASE + 0x518u)
#define UART_TXD REG(UART_BASE + 0x51Cu)
#define UART_BAUDRATE REG(UART_BASE + 0x524u)
#define UART_BAUD_115200 0x01D7E000u
#define UART_INT_RXDRDY (1u << 2)
#define UART_INT_TXDRDY (1u << 7)
#define UART_INT_ERROR (1u << 9)
#define MICROBIT_TX_PIN 24u
#define MICROBIT_RX_PIN 25u

#define TIMER0_BASE 0x40008000u
#define TIMER1_BASE 0x40009000u
#define TIMER2_BASE 0x4000A000u
#define TIMER_START(b) REG((b) + 0x000u)
#define TIMER_CLEAR(b) REG((b) + 0x00Cu)
#define TIMER_CAPTURE0(b) REG((b) + 0x040u)
#define TIMER_CAPTURE1(b) REG((b) + 0x044u)
#define TIMER_COMPARE0(b) REG((b) + 0x140u)
#define TIMER_SHORTS(b) REG((b) + 0x200u)
#define TIMER_INTENSET(b) REG((b) + 0x304u)
#define TIMER_MODE(b) REG((b) + 0x504u)
#define TIMER_BITMODE(b) REG((b) + 0x508u)
#define TIMER_PRESCALER(b) REG((b) + 0x510u)
#define TIMER_CC0(b) REG((b) + 0x540u)
#define TIMER_CC1(b) REG((b) + 0x544u)
#define TIMER_SHORT_COMPARE0_CLEAR 1u
#define TIMER_INT_COMPARE0 (1u << 16)
#define TIMER_BITMODE_32 3u

#define RNG_BASE 0x4000D000u
#define RNG_START REG(RNG_BASE + 0x000u)
#define RNG_STOP REG(RNG_BASE + 0x004u)
#define RNG_VALRDY REG(RNG_BASE + 0x100u)
#define RNG_VALUE REG(RNG_BASE + 0x508u)

#define NVIC_ISER REG(0xE000E100u)
#define IRQ_UART0 2u
#define IRQ_TIMER0 8u

#define RX_RING 256u
#define TX_RING 512u
#ifndef FW_MICROBIT_TICK_US
/* The control period. The braking law's worst fw_tick is about 24,000 instructions (an
 * integer square root and 64-bit divisions per side, telemetry due): more than 1 ms on a
 * 16 MHz Cortex-M0, so that tick runs late (pil_stats.late_ticks) and the next is on the
 * grid again. Where late ticks matter, build with 2000. */
#define FW_MICROBIT_TICK_US 1000u
#endif

static inline void irq_off(void) { __asm__ volatile("cpsid i" ::: "memory"); }
static inline void irq_on(void) { __asm__ volatile("cpsie i" ::: "memory"); }
static inline void wait_for_interrupt(void) { __asm__ volatile("wfi" ::: "memory"); }

static fw_t controller;
static fw_config_t config;

static volatile uint8_t rx_ring[RX_RING];
static volatile uint8_t rx_head; /* written by the ISR */
static volatile uint8_t rx_tail; /* written by the main loop */
static volatile uint8_t tx_ring[TX_RING];
static volatile uint16_t tx_head; /* written by the main loop */
static volatile uint16_t tx_tail; /* written by the ISR */
static volatile uint8_t tx_busy;
static volatile uint32_t grid_ticks; /* TIMER0 compares, written by its ISR */
static volatile uint32_t rx_stamp;   /* TIMER2 when the newest byte came in (ISR) */
static uint32_t rx_stamp_fed;        /* rx_stamp of the bytes being handed to the core */

#ifdef FW_PIL
/* Kept across resets (.noinit): the runner's faults, and the plant's world. */
__attribute__((section(".noinit"))) volatile pil_hooks_t pil_hooks;
__attribute__((section(".noinit"))) volatile pil_world_t pil_world;
pil_plant_t pil_plant;
static uint8_t dropout_seen;
static fw_pose_sample_t pose_taken;
static uint8_t pose_ready;
#endif

/* ------------------------------------------------------------------ clock */

static uint64_t clock_high;
static uint32_t clock_last;

/** Microseconds since boot, 64 bits (TIMER1 extended; called at least once per 71 min). */
static uint64_t now_us(void)
{
    uint32_t t;
    TIMER_CAPTURE0(TIMER1_BASE) = 1u;
    t = TIMER_CC0(TIMER1_BASE);
    if (t < clock_last) {
        clock_high += (uint64_t)1u << 32;
    }
    clock_last = t;
    return clock_high | t;
}

static uint32_t cycles(void)
{
    TIMER_CAPTURE0(TIMER2_BASE) = 1u;
    return TIMER_CC0(TIMER2_BASE);
}

/* ------------------------------------------------------------------ interrupts */

void UART0_IRQHandler(void)
{
    if (UART_ERROR != 0u) {
        UART_ERROR = 0u;
        UART_ERRORSRC = UART_ERRORSRC; /* write 1 to clear */
    }
    while (UART_RXDRDY != 0u) {
        uint8_t b;
        uint8_t next;
        UART_RXDRDY = 0u;
        b = (uint8_t)UART_RXD;
        TIMER_CAPTURE1(TIMER2_BASE) = 1u; /* CC[1]: the main loop captures into CC[0] */
        rx_stamp = TIMER_CC1(TIMER2_BASE);
        next = (uint8_t)(rx_head + 1u);
        if (next == rx_tail) {
            pil_stats.rx_overflows++;
        } else {
            rx_ring[rx_head] = b;
            rx_head = next;
        }
    }
    if (UART_TXDRDY != 0u) {
        UART_TXDRDY = 0u;
        if (tx_tail != tx_head) {
            UART_TXD = tx_ring[tx_tail];
            tx_tail = (uint16_t)((tx_tail + 1u) % TX_RING);
        } else {
            tx_busy = 0u;
        }
    }
}

void TIMER0_IRQHandler(void)
{
    if (TIMER_COMPARE0(TIMER0_BASE) != 0u) {
        TIMER_COMPARE0(TIMER0_BASE) = 0u;
        grid_ticks++;
    }
}

/* ------------------------------------------------------------------ HAL */

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    size_t i;
    uint16_t used;
    pil_note_answer(bytes, n, cycles() - rx_stamp_fed);
    irq_off();
    used = (uint16_t)((tx_head + TX_RING - tx_tail) % TX_RING);
    if (used + n >= TX_RING) {
        pil_stats.tx_drops++;
        irq_on();
        return;
    }
    for (i = 0u; i < n; i++) {
        tx_ring[tx_head] = bytes[i];
        tx_head = (uint16_t)((tx_head + 1u) % TX_RING);
    }
    if (tx_busy == 0u) {
        tx_busy = 1u;
        UART_TXD = tx_ring[tx_tail];
        tx_tail = (uint16_t)((tx_tail + 1u) % TX_RING);
    }
    irq_on();
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    (void)can_id;
    (void)data;
    (void)len;
}

uint16_t fw_hal_boot_nonce(void)
{
    uint16_t value = 0u;
    uint8_t i;
    RNG_START = 1u;
    for (i = 0u; i < 2u; i++) {
        uint32_t spin = 0u;
        while (RNG_VALRDY == 0u && spin < 100000u) {
            spin++;
        }
        RNG_VALRDY = 0u;
        value = (uint16_t)((value << 8) | (RNG_VALUE & 0xFFu));
    }
    RNG_STOP = 1u;
    return value;
}

#ifdef FW_PIL
void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    pil_plant.cmd[0] = left_um_s;
    pil_plant.cmd[1] = right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = pil_plant.reported[0];
    *right = pil_plant.reported[1];
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = pil_plant.speed[0];
    *right_um_s = pil_plant.speed[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    int32_t a = pil_plant.accel_mm_s2;
    out->yaw_rate_mrad_s = (int16_t)pil_plant.yaw_rate_mrad_s;
    out->accel_x_mm_s2 = (int16_t)(a > 32767 ? 32767 : (a < -32768 ? -32768 : a));
    out->accel_y_mm_s2 = 0;
    return 1;
}

void fw_hal_pose_sample(void)
{
    pil_plant_pose(&pil_plant, &pose_taken.x_mm, &pose_taken.y_mm, &pose_taken.yaw_ddeg);
    pose_taken.sigma_cm = 1u;
    pose_taken.taken_us = controller.now_us;
    pose_ready = 1u;
}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    if (pose_ready == 0u) {
        return 0;
    }
    pose_ready = 0u;
    *out = pose_taken;
    return 1;
}

/** The plant's step before each tick, and the encoder error line the dropout hook sets. */
static void view_update(void)
{
    pil_view_update(&controller, pil_plant.speed[0], pil_plant.speed[1]);
    pil_plant_pose(&pil_plant, (int32_t *)&pil_view.x_mm, (int32_t *)&pil_view.y_mm,
                   (int16_t *)&pil_view.yaw_ddeg);
    pil_view.travel_mm = (uint32_t)(pil_plant.travel_um / 1000u);
}

static void plant_before_tick(uint64_t now)
{
    uint8_t dropout = (uint8_t)((pil_hooks.encoder_dropout[0] ? 1u : 0u) |
                                (pil_hooks.encoder_dropout[1] ? 2u : 0u));
    pil_plant_step(&pil_plant, &pil_hooks, config.tick_us);
    pil_plant_keep(&pil_plant, &pil_world);
    if (dropout != 0u && dropout_seen == 0u) {
        fw_raise_fault(&controller, now, (uint8_t)RP_FAULT_CODE_ENCODER, 0u, true);
    } else if (dropout == 0u && dropout_seen != 0u) {
        fw_clear_fault(&controller, (uint8_t)RP_FAULT_CODE_ENCODER);
    }
    dropout_seen = dropout;
}
#else
/* A board port puts its motor driver and encoder counters here (docs/firmware.md). */
static int32_t wheel_cmd[2];

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    wheel_cmd[0] = left_um_s;
    wheel_cmd[1] = right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = 0;
    *right = 0;
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = wheel_cmd[0];
    *right_um_s = wheel_cmd[1];
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

static void plant_before_tick(uint64_t now) { (void)now; }

static void view_update(void) { pil_view_update(&controller, wheel_cmd[0], wheel_cmd[1]); }
#endif

/* ------------------------------------------------------------------ set-up and loop */

static void timers_init(uint32_t tick_us)
{
    TIMER_MODE(TIMER1_BASE) = 0u;
    TIMER_BITMODE(TIMER1_BASE) = TIMER_BITMODE_32;
    TIMER_PRESCALER(TIMER1_BASE) = 4u; /* 16 MHz / 2^4 = 1 MHz */
    TIMER_CLEAR(TIMER1_BASE) = 1u;
    TIMER_START(TIMER1_BASE) = 1u;

    TIMER_MODE(TIMER2_BASE) = 0u;
    TIMER_BITMODE(TIMER2_BASE) = TIMER_BITMODE_32;
    TIMER_PRESCALER(TIMER2_BASE) = 0u; /* 16 MHz: the CPU clock */
    TIMER_CLEAR(TIMER2_BASE) = 1u;
    TIMER_START(TIMER2_BASE) = 1u;
    pil_stats.tick_unit_hz = 16000000u;

    TIMER_MODE(TIMER0_BASE) = 0u;
    TIMER_BITMODE(TIMER0_BASE) = TIMER_BITMODE_32;
    TIMER_PRESCALER(TIMER0_BASE) = 4u;
    TIMER_CC0(TIMER0_BASE) = tick_us;
    TIMER_SHORTS(TIMER0_BASE) = TIMER_SHORT_COMPARE0_CLEAR;
    TIMER_INTENSET(TIMER0_BASE) = TIMER_INT_COMPARE0;
    TIMER_CLEAR(TIMER0_BASE) = 1u;
    NVIC_ISER = 1u << IRQ_TIMER0;
    TIMER_START(TIMER0_BASE) = 1u;
}

static void uart_init(void)
{
    UART_PSELTXD = MICROBIT_TX_PIN;
    UART_PSELRXD = MICROBIT_RX_PIN;
    UART_BAUDRATE = UART_BAUD_115200;
    UART_ENABLE = 4u;
    UART_INTENSET = UART_INT_RXDRDY | UART_INT_TXDRDY | UART_INT_ERROR;
    NVIC_ISER = 1u << IRQ_UART0;
    UART_STARTRX = 1u;
    UART_STARTTX = 1u;
}

/** Hand every byte the ISR queued to the core, in chunks. */
static void drain_rx(void)
{
    uint8_t chunk[32];
    size_t n = 0u;
    rx_stamp_fed = rx_stamp;
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
    config.tick_us = FW_MICROBIT_TICK_US;
    uart_init();
    timers_init(config.tick_us);
#ifdef FW_PIL
    pil_plant_init(&pil_plant, &config, FW_PIL_TRACK_UM, &pil_world);
#endif
    if (fw_init(&controller, &config, now_us()) != FW_OK) {
        for (;;) {
            wait_for_interrupt(); /* a configuration the core refuses: wheels at zero */
        }
    }
    for (;;) {
        uint32_t due;
        drain_rx();
        due = grid_ticks;
        if (due != done_ticks) {
            uint32_t start, spent;
            uint64_t now;
            if (due - done_ticks > 1u) {
                pil_stats.late_ticks += due - done_ticks - 1u;
            }
            done_ticks = due; /* the grid moved on: one tick at the time it is now */
            now = now_us();
            start = cycles();
            plant_before_tick(now);
            fw_tick(&controller, now);
            spent = cycles() - start;
            pil_stats.ticks++;
            view_update();
            pil_stats.tick_last = spent;
            if (spent > pil_stats.tick_max) {
                pil_stats.tick_max = spent;
            }
        }
        irq_off();
        if (rx_tail == rx_head && grid_ticks == done_ticks) {
            wait_for_interrupt(); /* wakes on a pending interrupt even while masked */
        }
        irq_on();
    }
}

/* ------------------------------------------------------------------ start-up */

extern uint32_t __data_load, __data_start, __data_end, __bss_start__, __bss_end__;
extern void __stack_top(void); /* a linker symbol, declared so that it fits the table */
void Reset_Handler(void);
void Default_Handler(void);

void Default_Handler(void)
{
    for (;;) {
    }
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
    (void)main();
    for (;;) {
    }
}

/* Cortex-M0 system vectors, then the nRF51's 32 peripheral interrupts. */
__attribute__((section(".vectors"), used)) static void (*const vectors[48])(void) = {
    __stack_top,     Reset_Handler,   Default_Handler, Default_Handler, /* NMI, HardFault */
    0,               0,               0,               0,
    0,               0,               0,               Default_Handler, /* SVCall */
    0,               0,               Default_Handler, Default_Handler, /* PendSV, SysTick */
    Default_Handler, Default_Handler, UART0_IRQHandler, Default_Handler, /* IRQ 0..3 */
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    TIMER0_IRQHandler, Default_Handler, Default_Handler, Default_Handler, /* IRQ 8.. */
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
};
