/**
 * @file simavr_harness.c
 * @brief The ATmega2560 processor-in-the-loop harness on libsimavr, loaded by
 *        emulator/pil/avr.py through ctypes (docs/firmware.md, "Processor in the loop").
 *
 * It owns one simulated ATmega2560 and nothing else: Python decides when and for how
 * many cycles it runs (real time or lockstep), moves the UART's bytes to and from the pty
 * or an in-memory line, and steps the twin. Between two runs Python reads the motor
 * outputs (Timer4's OCR4A/OCR4B/ICR4, PORTH's direction bits) and writes the sensors
 * (pil_sensors in the image's RAM). The CPU's sleeps are not slept here (simavr's default
 * sleeps in wall time): the caller maps cycles to its clock.
 *
 * UART0: bytes from the host wait in a FIFO here and enter the simulated USART as its
 * input FIFO has room (its XON/XOFF lines), paced by simavr at the configured baud rate
 * in simulated time; bytes the firmware transmits are collected for the caller. simavr's
 * own echo of the UART to stdout is turned off.
 */
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>

#define IN_CAP 8192u
#define OUT_CAP 65536u

typedef struct {
    avr_t *avr;
    elf_firmware_t fw;
    uint8_t in[IN_CAP];
    uint32_t in_head, in_len;
    uint8_t out[OUT_CAP];
    uint32_t out_len;
    uint32_t out_dropped;
    int xoff;
    avr_irq_t *uart_in;
} pil_avr_t;

static void on_uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    pil_avr_t *h = (pil_avr_t *)param;
    (void)irq;
    if (h->out_len < OUT_CAP) {
        h->out[h->out_len++] = (uint8_t)value;
    } else {
        h->out_dropped++;
    }
}

static void on_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((pil_avr_t *)param)->xoff = 0;
}

static void on_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((pil_avr_t *)param)->xoff = 1;
}

/** simavr's messages: errors and warnings to stderr, the rest (its "Loaded ..." lines on
 * stdout, which is the runner's protocol) dropped. */
static void log_quietly(avr_t *avr, const int level, const char *format, va_list ap)
{
    (void)avr;
    if (level <= LOG_WARNING && level > LOG_OUTPUT) {
        fputs("simavr: ", stderr);
        vfprintf(stderr, format, ap);
    }
}

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long;
}

/** Feed queued host bytes into the USART while its input FIFO has room. */
static void feed(pil_avr_t *h)
{
    while (h->in_len > 0u && !h->xoff) {
        uint8_t b = h->in[h->in_head];
        h->in_head = (h->in_head + 1u) % IN_CAP;
        h->in_len--;
        avr_raise_irq(h->uart_in, b);
    }
}

/** A new ATmega2560 at freq_hz running the ELF at path; NULL on failure (*err says why:
 * 1 the ELF, 2 the MCU). */
pil_avr_t *pil_avr_new(const char *path, uint32_t freq_hz, int *err)
{
    pil_avr_t *h = calloc(1u, sizeof *h);
    uint32_t flags = 0u;
    *err = 0;
    if (h == NULL) {
        *err = 3;
        return NULL;
    }
    avr_global_logger_set(log_quietly);
    if (elf_read_firmware(path, &h->fw) != 0) {
        *err = 1;
        free(h);
        return NULL;
    }
    h->avr = avr_make_mcu_by_name("atmega2560");
    if (h->avr == NULL) {
        *err = 2;
        free(h);
        return NULL;
    }
    avr_init(h->avr);
    h->avr->frequency = freq_hz;
    h->avr->log = 0;
    avr_load_firmware(h->avr, &h->fw);
    h->avr->frequency = freq_hz;
    h->avr->sleep = no_sleep;
    avr_ioctl(h->avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)AVR_UART_FLAG_STDIO;
    avr_ioctl(h->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    h->uart_in = avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_out, h);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            on_xon, h);
    avr_irq_register_notify(avr_io_getirq(h->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            on_xoff, h);
    return h;
}

void pil_avr_free(pil_avr_t *h)
{
    if (h != NULL) {
        avr_terminate(h->avr);
        free(h->avr);
        free(h);
    }
}

/** Cycles since the simulation started. */
uint64_t pil_avr_cycles(const pil_avr_t *h) { return h->avr->cycle; }

/** Queue bytes from the host for the USART; returns how many fit (the rest: drop). */
uint32_t pil_avr_uart_send(pil_avr_t *h, const uint8_t *bytes, uint32_t n)
{
    uint32_t i;
    for (i = 0u; i < n && h->in_len < IN_CAP; i++) {
        h->in[(h->in_head + h->in_len) % IN_CAP] = bytes[i];
        h->in_len++;
    }
    feed(h);
    return i;
}

/** Bytes the firmware transmitted since the last call (up to cap); returns the count. */
uint32_t pil_avr_uart_take(pil_avr_t *h, uint8_t *out, uint32_t cap)
{
    uint32_t n = h->out_len < cap ? h->out_len : cap;
    memcpy(out, h->out, n);
    memmove(h->out, h->out + n, h->out_len - n);
    h->out_len -= n;
    return n;
}

/** Host bytes still waiting to enter the USART. */
uint32_t pil_avr_uart_pending(const pil_avr_t *h) { return h->in_len; }

/**
 * Run until the cycle counter reaches `until` (a sleeping CPU skips to its next timer
 * event, so it may pass it). Returns simavr's state: 2 running, 3 sleeping; 7 done or
 * 8 crashed end the simulation.
 */
int pil_avr_run(pil_avr_t *h, uint64_t until)
{
    int state = h->avr->state;
    while (h->avr->cycle < until) {
        feed(h);
        state = avr_run(h->avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            break;
        }
    }
    feed(h);
    return state;
}

/** Read n bytes of the data space (registers, I/O, SRAM) at addr. */
void pil_avr_read(const pil_avr_t *h, uint16_t addr, uint8_t *out, uint16_t n)
{
    memcpy(out, h->avr->data + addr, n);
}

/** Write n bytes into SRAM at addr (the image's globals; not for I/O registers). */
void pil_avr_write(pil_avr_t *h, uint16_t addr, const uint8_t *bytes, uint16_t n)
{
    memcpy(h->avr->data + addr, bytes, n);
}

/** A reset of the MCU (the reset pin): registers and peripherals to their reset state,
 * the program from address 0; the harness's UART queues are emptied. */
void pil_avr_reset(pil_avr_t *h)
{
    avr_reset(h->avr);
    h->in_head = 0u;
    h->in_len = 0u;
    h->out_len = 0u;
    h->xoff = 0;
}
