/**
 * @file main.c
 * @brief A bare-metal skeleton port of the firmware core, used to cross-build it for
 *        real MCUs and measure its flash and RAM (tests/firmware_proto/test_fw_cross.py).
 *
 * The HAL talks to memory-mapped registers at made-up addresses (volatile, so nothing
 * is optimised away); a real port replaces them with its UART, CAN, PWM, encoder
 * timer and SysTick drivers (README.md in the parent folder). It is built, never run.
 */
#include "../fw.h"

#define REG32(addr) (*(volatile uint32_t *)(addr))
#define REG8(addr) (*(volatile uint8_t *)(addr))

#ifdef __AVR__
#define IO_BASE 0x2000u
#else
#define IO_BASE 0x40000000u
#endif

#define UART_DR REG8(IO_BASE + 0x00u)
#define UART_RX_READY REG8(IO_BASE + 0x04u)
#define PWM_LEFT REG32(IO_BASE + 0x10u)
#define PWM_RIGHT REG32(IO_BASE + 0x14u)
#define ENC_LEFT REG32(IO_BASE + 0x20u)
#define ENC_RIGHT REG32(IO_BASE + 0x24u)
#define SPEED_LEFT REG32(IO_BASE + 0x28u)
#define SPEED_RIGHT REG32(IO_BASE + 0x2Cu)
#define CLOCK_US REG32(IO_BASE + 0x30u)
#define RNG REG32(IO_BASE + 0x34u)
#define CAN_ID REG32(IO_BASE + 0x40u)
#define CAN_DATA REG8(IO_BASE + 0x44u)

static fw_t controller;

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    PWM_LEFT = (uint32_t)left_um_s;
    PWM_RIGHT = (uint32_t)right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = (int32_t)ENC_LEFT;
    *right = (int32_t)ENC_RIGHT;
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = (int32_t)SPEED_LEFT;
    *right_um_s = (int32_t)SPEED_RIGHT;
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

uint16_t fw_hal_boot_nonce(void) { return (uint16_t)RNG; }

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        UART_DR = bytes[i];
    }
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    uint8_t i;
    CAN_ID = can_id;
    for (i = 0u; i < len; i++) {
        CAN_DATA = data[i];
    }
}

/** A 64-bit microsecond clock from a free-running 32-bit counter. */
static uint64_t now_us(void)
{
    static uint64_t high;
    static uint32_t last;
    const uint32_t t = CLOCK_US;
    if (t < last) {
        high += (uint64_t)1u << 32;
    }
    last = t;
    return high | t;
}

int main(void)
{
    fw_config_t cfg;
    uint64_t next;
    fw_default_config(&cfg);
    if (fw_init(&controller, &cfg, now_us()) != FW_OK) {
        for (;;) {
            /* a configuration the core refuses: the wheels stay at zero */
        }
    }
    next = now_us();
    for (;;) {
        if (UART_RX_READY != 0u) {
            const uint8_t b = UART_DR;
            fw_on_bytes(&controller, now_us(), &b, 1u);
        }
        if (now_us() >= next) {
            next += cfg.tick_us;
            fw_tick(&controller, now_us());
        }
    }
}
