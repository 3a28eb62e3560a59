/**
 * @file pil_port.c
 * @brief The counters and the view every processor-in-the-loop port keeps (pil_port.h).
 */
#include "pil_port.h"

volatile pil_stats_t pil_stats;
volatile pil_view_t pil_view;

void pil_view_update(const fw_t *c, int32_t speed_left_um_s, int32_t speed_right_um_s)
{
    pil_view.commanded_um_s[0] = c->commanded[0];
    pil_view.commanded_um_s[1] = c->commanded[1];
    pil_view.speed_um_s[0] = speed_left_um_s;
    pil_view.speed_um_s[1] = speed_right_um_s;
    pil_view.boot_nonce = c->boot_nonce;
    pil_view.rx_errors = (uint16_t)c->rx_errors;
    pil_view.state = c->state;
    pil_view.latch = c->latch;
    pil_view.faults = c->faults;
    pil_view.queue_depth = fw_queue_depth(c);
}

void pil_sensors_copy(pil_sensors_t *out, const volatile pil_sensors_t *in)
{
    uint8_t tries;
    for (tries = 0u; tries < 8u; tries++) {
        const volatile uint8_t *src = (const volatile uint8_t *)in;
        uint8_t *dst = (uint8_t *)out;
        const uint8_t seq = in->seq;
        size_t i;
        for (i = 0u; i < sizeof *out; i++) {
            dst[i] = src[i];
        }
        if (in->seq == seq) {
            return;
        }
    }
}

void pil_note_answer(const uint8_t *frame, size_t n, uint32_t spent)
{
    uint8_t id;
    if (n < 3u) {
        return;
    }
    id = frame[1] == 1u ? 0u : frame[2]; /* 0x00, COBS(id, seq, ...), 0x00 */
    if (id == RP_MSG_STOP_ACK) {
        pil_stats.stop_ack_last = spent;
        if (spent > pil_stats.stop_ack_max) {
            pil_stats.stop_ack_max = spent;
        }
    } else if (id == RP_MSG_IDENT) {
        pil_stats.ident_last = spent;
    }
}
