/* GENERATED from firmware_proto/wire/protocol.toml by firmware_proto/wire/codegen/c.py
 * (`rover frame generate`). Do not edit: edit the spec and regenerate. */

#include "rover_msgs.h"

int rp_err_field_index(int err)
{
    if (err <= RP_ERR_FIELD_BASE && err > RP_ERR_FIELD_BASE - 64) {
        return RP_ERR_FIELD_BASE - err;
    }
    if (err <= RP_ERR_LIMIT_BASE && err > RP_ERR_LIMIT_BASE - 64) {
        return RP_ERR_LIMIT_BASE - err;
    }
    return -1;
}

bool rp_err_is_limit(int err)
{
    return err <= RP_ERR_LIMIT_BASE && err > RP_ERR_LIMIT_BASE - 64;
}

int rp_stop_pack(const rp_stop_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 3u) {
        return RP_ERR_BUFFER;
    }
    if (msg->stop_id < INT32_C(1)) {
        return RP_ERR_FIELD(0);
    }
    if (msg->source > INT32_C(4)) {
        return RP_ERR_FIELD(1);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->stop_id & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->source & UINT64_C(0xFF)) << 16;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    return 3;
}

int rp_stop_unpack(rp_stop_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 3u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    const int64_t f_stop_id = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_source = (int64_t)((w >> 16) & UINT64_C(0xFF));
    if (f_stop_id < 1) {
        return RP_ERR_FIELD(0);
    }
    if (f_source > 4) {
        return RP_ERR_FIELD(1);
    }
    msg->stop_id = (uint16_t)f_stop_id;
    msg->source = (uint8_t)f_source;
    return RP_OK;
}

int rp_stop_ack_pack(const rp_stop_ack_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 4u) {
        return RP_ERR_BUFFER;
    }
    if (msg->state > INT32_C(4)) {
        return RP_ERR_FIELD(1);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->stop_id & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->state & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->latch_gen & UINT64_C(0xFF)) << 24;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    return 4;
}

int rp_stop_ack_unpack(rp_stop_ack_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 4u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    const int64_t f_stop_id = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_state = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_latch_gen = (int64_t)((w >> 24) & UINT64_C(0xFF));
    if (f_state > 4) {
        return RP_ERR_FIELD(1);
    }
    msg->stop_id = (uint16_t)f_stop_id;
    msg->state = (uint8_t)f_state;
    msg->latch_gen = (uint8_t)f_latch_gen;
    return RP_OK;
}

int rp_clear_stop_pack(const rp_clear_stop_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 3u) {
        return RP_ERR_BUFFER;
    }
    if (msg->stop_id < INT32_C(1)) {
        return RP_ERR_FIELD(0);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->stop_id & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->latch_gen & UINT64_C(0xFF)) << 16;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    return 3;
}

int rp_clear_stop_unpack(rp_clear_stop_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 3u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    const int64_t f_stop_id = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_latch_gen = (int64_t)((w >> 16) & UINT64_C(0xFF));
    if (f_stop_id < 1) {
        return RP_ERR_FIELD(0);
    }
    msg->stop_id = (uint16_t)f_stop_id;
    msg->latch_gen = (uint8_t)f_latch_gen;
    return RP_OK;
}

int rp_clear_ack_pack(const rp_clear_ack_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 4u) {
        return RP_ERR_BUFFER;
    }
    if (msg->result > INT32_C(3)) {
        return RP_ERR_FIELD(1);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->stop_id & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->result & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->latch_gen & UINT64_C(0xFF)) << 24;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    return 4;
}

int rp_clear_ack_unpack(rp_clear_ack_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 4u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    const int64_t f_stop_id = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_result = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_latch_gen = (int64_t)((w >> 24) & UINT64_C(0xFF));
    if (f_result > 3) {
        return RP_ERR_FIELD(1);
    }
    msg->stop_id = (uint16_t)f_stop_id;
    msg->result = (uint8_t)f_result;
    msg->latch_gen = (uint8_t)f_latch_gen;
    return RP_OK;
}

int rp_motion_pack(const rp_motion_t *msg, bool strict, uint8_t *out, size_t cap)
{
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 6u) {
        return RP_ERR_BUFFER;
    }
    if (strict) {
        if (msg->command > INT32_C(4)) {
            return RP_ERR_LIMIT(1);
        }
        if (msg->speed > INT32_C(60)) {
            return RP_ERR_LIMIT(2);
        }
        if (msg->distance > INT32_C(30000)) {
            return RP_ERR_LIMIT(3);
        }
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->seq & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->command & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->speed & UINT64_C(0xFF)) << 24;
    w |= ((uint64_t)msg->distance & UINT64_C(0xFFFF)) << 32;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    return 6;
}

int rp_motion_unpack(rp_motion_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 6u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    const int64_t f_seq = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_command = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_speed = (int64_t)((w >> 24) & UINT64_C(0xFF));
    const int64_t f_distance = (int64_t)((w >> 32) & UINT64_C(0xFFFF));
    msg->seq = (uint16_t)f_seq;
    msg->command = (uint8_t)f_command;
    msg->speed = (uint8_t)f_speed;
    msg->distance = (uint16_t)f_distance;
    return RP_OK;
}

int rp_ack_pack(const rp_ack_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 5u) {
        return RP_ERR_BUFFER;
    }
    if (msg->result > INT32_C(6)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->field > INT32_C(3)) {
        return RP_ERR_FIELD(2);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->seq & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->result & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->field & UINT64_C(0xFF)) << 24;
    w |= ((uint64_t)msg->queue_depth & UINT64_C(0xFF)) << 32;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    return 5;
}

int rp_ack_unpack(rp_ack_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 5u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    const int64_t f_seq = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_result = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_field = (int64_t)((w >> 24) & UINT64_C(0xFF));
    const int64_t f_queue_depth = (int64_t)((w >> 32) & UINT64_C(0xFF));
    if (f_result > 6) {
        return RP_ERR_FIELD(1);
    }
    if (f_field > 3) {
        return RP_ERR_FIELD(2);
    }
    msg->seq = (uint16_t)f_seq;
    msg->result = (uint8_t)f_result;
    msg->field = (uint8_t)f_field;
    msg->queue_depth = (uint8_t)f_queue_depth;
    return RP_OK;
}

int rp_status_pack(const rp_status_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 6u) {
        return RP_ERR_BUFFER;
    }
    if (msg->state > INT32_C(2)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->reason > INT32_C(5)) {
        return RP_ERR_FIELD(2);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->seq & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->state & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->reason & UINT64_C(0xFF)) << 24;
    w |= ((uint64_t)msg->travel & UINT64_C(0xFFFF)) << 32;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    return 6;
}

int rp_status_unpack(rp_status_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 6u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    const int64_t f_seq = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_state = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_reason = (int64_t)((w >> 24) & UINT64_C(0xFF));
    const int64_t f_travel = (int64_t)((w >> 32) & UINT64_C(0xFFFF));
    if (f_state > 2) {
        return RP_ERR_FIELD(1);
    }
    if (f_reason > 5) {
        return RP_ERR_FIELD(2);
    }
    msg->seq = (uint16_t)f_seq;
    msg->state = (uint8_t)f_state;
    msg->reason = (uint8_t)f_reason;
    msg->travel = (uint16_t)f_travel;
    return RP_OK;
}

int rp_stopped_pack(const rp_stopped_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 6u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->stop_id & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->distance_mm & UINT64_C(0xFFFF)) << 16;
    w |= ((uint64_t)msg->duration_ms & UINT64_C(0xFFFF)) << 32;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    return 6;
}

int rp_stopped_unpack(rp_stopped_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 6u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    const int64_t f_stop_id = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_distance_mm = (int64_t)((w >> 16) & UINT64_C(0xFFFF));
    const int64_t f_duration_ms = (int64_t)((w >> 32) & UINT64_C(0xFFFF));
    msg->stop_id = (uint16_t)f_stop_id;
    msg->distance_mm = (uint16_t)f_distance_mm;
    msg->duration_ms = (uint16_t)f_duration_ms;
    return RP_OK;
}

int rp_fault_pack(const rp_fault_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 5u) {
        return RP_ERR_BUFFER;
    }
    if (msg->code < INT32_C(1) || msg->code > INT32_C(8)) {
        return RP_ERR_FIELD(0);
    }
    if (msg->active > INT32_C(1)) {
        return RP_ERR_FIELD(1);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->code & UINT64_C(0xFF));
    w |= ((uint64_t)msg->active & UINT64_C(0x1)) << 8;
    w |= ((uint64_t)msg->detail & UINT64_C(0xFFFF)) << 16;
    w |= ((uint64_t)msg->latch_gen & UINT64_C(0xFF)) << 32;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    return 5;
}

int rp_fault_unpack(rp_fault_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 5u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    const int64_t f_code = (int64_t)(w & UINT64_C(0xFF));
    const int64_t f_active = (int64_t)((w >> 8) & UINT64_C(0x1));
    const int64_t f_detail = (int64_t)((w >> 16) & UINT64_C(0xFFFF));
    const int64_t f_latch_gen = (int64_t)((w >> 32) & UINT64_C(0xFF));
    if (f_code < 1 || f_code > 8) {
        return RP_ERR_FIELD(0);
    }
    msg->code = (uint8_t)f_code;
    msg->active = (uint8_t)f_active;
    msg->detail = (uint16_t)f_detail;
    msg->latch_gen = (uint8_t)f_latch_gen;
    return RP_OK;
}

int rp_heartbeat_pack(const rp_heartbeat_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    if (msg->state > INT32_C(4)) {
        return RP_ERR_FIELD(0);
    }
    if (msg->stop_latched > INT32_C(1)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->handshake_ok > INT32_C(1)) {
        return RP_ERR_FIELD(2);
    }
    if (msg->latch_stop > INT32_C(1)) {
        return RP_ERR_FIELD(3);
    }
    if (msg->latch_watchdog > INT32_C(1)) {
        return RP_ERR_FIELD(4);
    }
    if (msg->latch_fault > INT32_C(1)) {
        return RP_ERR_FIELD(5);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->state & UINT64_C(0x7));
    w |= ((uint64_t)msg->stop_latched & UINT64_C(0x1)) << 3;
    w |= ((uint64_t)msg->handshake_ok & UINT64_C(0x1)) << 4;
    w |= ((uint64_t)msg->latch_stop & UINT64_C(0x1)) << 5;
    w |= ((uint64_t)msg->latch_watchdog & UINT64_C(0x1)) << 6;
    w |= ((uint64_t)msg->latch_fault & UINT64_C(0x1)) << 7;
    w |= ((uint64_t)msg->fault_bits & UINT64_C(0xFF)) << 8;
    w |= ((uint64_t)msg->queue_depth & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->boot_nonce & UINT64_C(0xFFFF)) << 24;
    w |= ((uint64_t)msg->rx_errors & UINT64_C(0xFFFF)) << 40;
    w |= ((uint64_t)msg->latch_gen & UINT64_C(0xFF)) << 56;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_heartbeat_unpack(rp_heartbeat_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_state = (int64_t)(w & UINT64_C(0x7));
    const int64_t f_stop_latched = (int64_t)((w >> 3) & UINT64_C(0x1));
    const int64_t f_handshake_ok = (int64_t)((w >> 4) & UINT64_C(0x1));
    const int64_t f_latch_stop = (int64_t)((w >> 5) & UINT64_C(0x1));
    const int64_t f_latch_watchdog = (int64_t)((w >> 6) & UINT64_C(0x1));
    const int64_t f_latch_fault = (int64_t)((w >> 7) & UINT64_C(0x1));
    const int64_t f_fault_bits = (int64_t)((w >> 8) & UINT64_C(0xFF));
    const int64_t f_queue_depth = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_boot_nonce = (int64_t)((w >> 24) & UINT64_C(0xFFFF));
    const int64_t f_rx_errors = (int64_t)((w >> 40) & UINT64_C(0xFFFF));
    const int64_t f_latch_gen = (int64_t)((w >> 56) & UINT64_C(0xFF));
    if (f_state > 4) {
        return RP_ERR_FIELD(0);
    }
    msg->state = (uint8_t)f_state;
    msg->stop_latched = (uint8_t)f_stop_latched;
    msg->handshake_ok = (uint8_t)f_handshake_ok;
    msg->latch_stop = (uint8_t)f_latch_stop;
    msg->latch_watchdog = (uint8_t)f_latch_watchdog;
    msg->latch_fault = (uint8_t)f_latch_fault;
    msg->fault_bits = (uint8_t)f_fault_bits;
    msg->queue_depth = (uint8_t)f_queue_depth;
    msg->boot_nonce = (uint16_t)f_boot_nonce;
    msg->rx_errors = (uint16_t)f_rx_errors;
    msg->latch_gen = (uint8_t)f_latch_gen;
    return RP_OK;
}

int rp_host_heartbeat_pack(const rp_host_heartbeat_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 2u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->counter & UINT64_C(0xFFFF));
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    return 2;
}

int rp_host_heartbeat_unpack(rp_host_heartbeat_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 2u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    const int64_t f_counter = (int64_t)(w & UINT64_C(0xFFFF));
    msg->counter = (uint16_t)f_counter;
    return RP_OK;
}

int rp_encoders_pack(const rp_encoders_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    if (msg->left < INT32_C(-8388608) || msg->left > INT32_C(8388607)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->right < INT32_C(-8388608) || msg->right > INT32_C(8388607)) {
        return RP_ERR_FIELD(2);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->t_ms & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->left & UINT64_C(0xFFFFFF)) << 16;
    w |= ((uint64_t)msg->right & UINT64_C(0xFFFFFF)) << 40;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_encoders_unpack(rp_encoders_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_t_ms = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_left = (int64_t)((w >> 16) & UINT64_C(0xFFFFFF)) - (int64_t)(((w >> 16) & (UINT64_C(1) << 23)) << 1);
    const int64_t f_right = (int64_t)((w >> 40) & UINT64_C(0xFFFFFF)) - (int64_t)(((w >> 40) & (UINT64_C(1) << 23)) << 1);
    msg->t_ms = (uint16_t)f_t_ms;
    msg->left = (int32_t)f_left;
    msg->right = (int32_t)f_right;
    return RP_OK;
}

int rp_wheel_speeds_pack(const rp_wheel_speeds_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    if (msg->left_mm_s < INT32_C(-2048) || msg->left_mm_s > INT32_C(2047)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->right_mm_s < INT32_C(-2048) || msg->right_mm_s > INT32_C(2047)) {
        return RP_ERR_FIELD(2);
    }
    if (msg->left_target_mm_s < INT32_C(-2048) || msg->left_target_mm_s > INT32_C(2047)) {
        return RP_ERR_FIELD(3);
    }
    if (msg->right_target_mm_s < INT32_C(-2048) || msg->right_target_mm_s > INT32_C(2047)) {
        return RP_ERR_FIELD(4);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->t_ms & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->left_mm_s & UINT64_C(0xFFF)) << 16;
    w |= ((uint64_t)msg->right_mm_s & UINT64_C(0xFFF)) << 28;
    w |= ((uint64_t)msg->left_target_mm_s & UINT64_C(0xFFF)) << 40;
    w |= ((uint64_t)msg->right_target_mm_s & UINT64_C(0xFFF)) << 52;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_wheel_speeds_unpack(rp_wheel_speeds_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_t_ms = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_left_mm_s = (int64_t)((w >> 16) & UINT64_C(0xFFF)) - (int64_t)(((w >> 16) & (UINT64_C(1) << 11)) << 1);
    const int64_t f_right_mm_s = (int64_t)((w >> 28) & UINT64_C(0xFFF)) - (int64_t)(((w >> 28) & (UINT64_C(1) << 11)) << 1);
    const int64_t f_left_target_mm_s = (int64_t)((w >> 40) & UINT64_C(0xFFF)) - (int64_t)(((w >> 40) & (UINT64_C(1) << 11)) << 1);
    const int64_t f_right_target_mm_s = (int64_t)((w >> 52) & UINT64_C(0xFFF)) - (int64_t)(((w >> 52) & (UINT64_C(1) << 11)) << 1);
    msg->t_ms = (uint16_t)f_t_ms;
    msg->left_mm_s = (int16_t)f_left_mm_s;
    msg->right_mm_s = (int16_t)f_right_mm_s;
    msg->left_target_mm_s = (int16_t)f_left_target_mm_s;
    msg->right_target_mm_s = (int16_t)f_right_target_mm_s;
    return RP_OK;
}

int rp_imu_pack(const rp_imu_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->t_ms & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->yaw_rate_mrad_s & UINT64_C(0xFFFF)) << 16;
    w |= ((uint64_t)msg->accel_x_mm_s2 & UINT64_C(0xFFFF)) << 32;
    w |= ((uint64_t)msg->accel_y_mm_s2 & UINT64_C(0xFFFF)) << 48;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_imu_unpack(rp_imu_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_t_ms = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_yaw_rate_mrad_s = (int64_t)((w >> 16) & UINT64_C(0xFFFF)) - (int64_t)(((w >> 16) & (UINT64_C(1) << 15)) << 1);
    const int64_t f_accel_x_mm_s2 = (int64_t)((w >> 32) & UINT64_C(0xFFFF)) - (int64_t)(((w >> 32) & (UINT64_C(1) << 15)) << 1);
    const int64_t f_accel_y_mm_s2 = (int64_t)((w >> 48) & UINT64_C(0xFFFF)) - (int64_t)(((w >> 48) & (UINT64_C(1) << 15)) << 1);
    msg->t_ms = (uint16_t)f_t_ms;
    msg->yaw_rate_mrad_s = (int16_t)f_yaw_rate_mrad_s;
    msg->accel_x_mm_s2 = (int16_t)f_accel_x_mm_s2;
    msg->accel_y_mm_s2 = (int16_t)f_accel_y_mm_s2;
    return RP_OK;
}

int rp_pose_pack(const rp_pose_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    if (msg->x_mm < INT32_C(-524288) || msg->x_mm > INT32_C(524287)) {
        return RP_ERR_FIELD(0);
    }
    if (msg->y_mm < INT32_C(-524288) || msg->y_mm > INT32_C(524287)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->yaw_ddeg < INT32_C(-1800) || msg->yaw_ddeg > INT32_C(1800)) {
        return RP_ERR_FIELD(2);
    }
    if (msg->sigma_cm > INT32_C(15)) {
        return RP_ERR_FIELD(3);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->x_mm & UINT64_C(0xFFFFF));
    w |= ((uint64_t)msg->y_mm & UINT64_C(0xFFFFF)) << 20;
    w |= ((uint64_t)msg->yaw_ddeg & UINT64_C(0xFFF)) << 40;
    w |= ((uint64_t)msg->sigma_cm & UINT64_C(0xF)) << 52;
    w |= ((uint64_t)msg->age_4ms & UINT64_C(0xFF)) << 56;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_pose_unpack(rp_pose_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_x_mm = (int64_t)(w & UINT64_C(0xFFFFF)) - (int64_t)((w & (UINT64_C(1) << 19)) << 1);
    const int64_t f_y_mm = (int64_t)((w >> 20) & UINT64_C(0xFFFFF)) - (int64_t)(((w >> 20) & (UINT64_C(1) << 19)) << 1);
    const int64_t f_yaw_ddeg = (int64_t)((w >> 40) & UINT64_C(0xFFF)) - (int64_t)(((w >> 40) & (UINT64_C(1) << 11)) << 1);
    const int64_t f_sigma_cm = (int64_t)((w >> 52) & UINT64_C(0xF));
    const int64_t f_age_4ms = (int64_t)((w >> 56) & UINT64_C(0xFF));
    if (f_yaw_ddeg < -1800 || f_yaw_ddeg > 1800) {
        return RP_ERR_FIELD(2);
    }
    msg->x_mm = (int32_t)f_x_mm;
    msg->y_mm = (int32_t)f_y_mm;
    msg->yaw_ddeg = (int16_t)f_yaw_ddeg;
    msg->sigma_cm = (uint8_t)f_sigma_cm;
    msg->age_4ms = (uint8_t)f_age_4ms;
    return RP_OK;
}

int rp_progress_pack(const rp_progress_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    if (msg->ended_state > INT32_C(2)) {
        return RP_ERR_FIELD(1);
    }
    if (msg->ended_reason > INT32_C(5)) {
        return RP_ERR_FIELD(2);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->ended_seq & UINT64_C(0xFFFF));
    w |= ((uint64_t)msg->ended_state & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->ended_reason & UINT64_C(0xFF)) << 24;
    w |= ((uint64_t)msg->ended_count & UINT64_C(0xFFFF)) << 32;
    w |= ((uint64_t)msg->travel & UINT64_C(0xFFFF)) << 48;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_progress_unpack(rp_progress_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_ended_seq = (int64_t)(w & UINT64_C(0xFFFF));
    const int64_t f_ended_state = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_ended_reason = (int64_t)((w >> 24) & UINT64_C(0xFF));
    const int64_t f_ended_count = (int64_t)((w >> 32) & UINT64_C(0xFFFF));
    const int64_t f_travel = (int64_t)((w >> 48) & UINT64_C(0xFFFF));
    if (f_ended_state > 2) {
        return RP_ERR_FIELD(1);
    }
    if (f_ended_reason > 5) {
        return RP_ERR_FIELD(2);
    }
    msg->ended_seq = (uint16_t)f_ended_seq;
    msg->ended_state = (uint8_t)f_ended_state;
    msg->ended_reason = (uint8_t)f_ended_reason;
    msg->ended_count = (uint16_t)f_ended_count;
    msg->travel = (uint16_t)f_travel;
    return RP_OK;
}

int rp_hello_pack(const rp_hello_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 3u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->protocol_version & UINT64_C(0xFF));
    w |= ((uint64_t)msg->schema_hash & UINT64_C(0xFFFF)) << 8;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    return 3;
}

int rp_hello_unpack(rp_hello_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 3u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    const int64_t f_protocol_version = (int64_t)(w & UINT64_C(0xFF));
    const int64_t f_schema_hash = (int64_t)((w >> 8) & UINT64_C(0xFFFF));
    msg->protocol_version = (uint8_t)f_protocol_version;
    msg->schema_hash = (uint16_t)f_schema_hash;
    return RP_OK;
}

int rp_ident_pack(const rp_ident_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 8u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->protocol_version & UINT64_C(0xFF));
    w |= ((uint64_t)msg->firmware_major & UINT64_C(0xFF)) << 8;
    w |= ((uint64_t)msg->firmware_minor & UINT64_C(0xFF)) << 16;
    w |= ((uint64_t)msg->firmware_patch & UINT64_C(0xFF)) << 24;
    w |= ((uint64_t)msg->schema_hash & UINT64_C(0xFFFF)) << 32;
    w |= ((uint64_t)msg->boot_nonce & UINT64_C(0xFFFF)) << 48;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    out[6] = (uint8_t)(w >> 48);
    out[7] = (uint8_t)(w >> 56);
    return 8;
}

int rp_ident_unpack(rp_ident_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 8u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    w |= (uint64_t)payload[6] << 48;
    w |= (uint64_t)payload[7] << 56;
    const int64_t f_protocol_version = (int64_t)(w & UINT64_C(0xFF));
    const int64_t f_firmware_major = (int64_t)((w >> 8) & UINT64_C(0xFF));
    const int64_t f_firmware_minor = (int64_t)((w >> 16) & UINT64_C(0xFF));
    const int64_t f_firmware_patch = (int64_t)((w >> 24) & UINT64_C(0xFF));
    const int64_t f_schema_hash = (int64_t)((w >> 32) & UINT64_C(0xFFFF));
    const int64_t f_boot_nonce = (int64_t)((w >> 48) & UINT64_C(0xFFFF));
    msg->protocol_version = (uint8_t)f_protocol_version;
    msg->firmware_major = (uint8_t)f_firmware_major;
    msg->firmware_minor = (uint8_t)f_firmware_minor;
    msg->firmware_patch = (uint8_t)f_firmware_patch;
    msg->schema_hash = (uint16_t)f_schema_hash;
    msg->boot_nonce = (uint16_t)f_boot_nonce;
    return RP_OK;
}

int rp_set_param_pack(const rp_set_param_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 5u) {
        return RP_ERR_BUFFER;
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->param & UINT64_C(0xFF));
    w |= ((uint64_t)msg->value & UINT64_C(0xFFFFFFFF)) << 8;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    return 5;
}

int rp_set_param_unpack(rp_set_param_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 5u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    const int64_t f_param = (int64_t)(w & UINT64_C(0xFF));
    const int64_t f_value = (int64_t)((w >> 8) & UINT64_C(0xFFFFFFFF)) - (int64_t)(((w >> 8) & (UINT64_C(1) << 31)) << 1);
    msg->param = (uint8_t)f_param;
    msg->value = (int32_t)f_value;
    return RP_OK;
}

int rp_param_value_pack(const rp_param_value_t *msg, bool strict, uint8_t *out, size_t cap)
{
    (void)strict;
    if (msg == NULL || out == NULL) {
        return RP_ERR_NULL;
    }
    if (cap < 6u) {
        return RP_ERR_BUFFER;
    }
    if (msg->result > INT32_C(2)) {
        return RP_ERR_FIELD(1);
    }
    uint64_t w = 0;
    w |= ((uint64_t)msg->param & UINT64_C(0xFF));
    w |= ((uint64_t)msg->result & UINT64_C(0xFF)) << 8;
    w |= ((uint64_t)msg->value & UINT64_C(0xFFFFFFFF)) << 16;
    out[0] = (uint8_t)(w);
    out[1] = (uint8_t)(w >> 8);
    out[2] = (uint8_t)(w >> 16);
    out[3] = (uint8_t)(w >> 24);
    out[4] = (uint8_t)(w >> 32);
    out[5] = (uint8_t)(w >> 40);
    return 6;
}

int rp_param_value_unpack(rp_param_value_t *msg, const uint8_t *payload, size_t len)
{
    if (msg == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len != 6u) {
        return RP_ERR_LENGTH;
    }
    uint64_t w = 0;
    w |= (uint64_t)payload[0];
    w |= (uint64_t)payload[1] << 8;
    w |= (uint64_t)payload[2] << 16;
    w |= (uint64_t)payload[3] << 24;
    w |= (uint64_t)payload[4] << 32;
    w |= (uint64_t)payload[5] << 40;
    const int64_t f_param = (int64_t)(w & UINT64_C(0xFF));
    const int64_t f_result = (int64_t)((w >> 8) & UINT64_C(0xFF));
    const int64_t f_value = (int64_t)((w >> 16) & UINT64_C(0xFFFFFFFF)) - (int64_t)(((w >> 16) & (UINT64_C(1) << 31)) << 1);
    if (f_result > 2) {
        return RP_ERR_FIELD(1);
    }
    msg->param = (uint8_t)f_param;
    msg->result = (uint8_t)f_result;
    msg->value = (int32_t)f_value;
    return RP_OK;
}

/* RP_NO_FIELD_INFO leaves out the field descriptions (names, ranges, limits: about
 * 3.4 KiB on a Cortex-M0+) that firmware which only packs and unpacks never reads;
 * rp_msg_info() then gives n_fields 0 and fields NULL. */
#ifdef RP_NO_FIELD_INFO
#define RP_FIELDS(n, table) 0u, NULL
#else

static const rp_field_info_t fields_stop[] = {
    {"stop_id", 16u, false, INT64_C(1), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"source", 8u, false, INT64_C(0), INT64_C(4), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_stop_ack[] = {
    {"stop_id", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"state", 8u, false, INT64_C(0), INT64_C(4), false, INT64_C(0), INT64_C(0)},
    {"latch_gen", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_clear_stop[] = {
    {"stop_id", 16u, false, INT64_C(1), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"latch_gen", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_clear_ack[] = {
    {"stop_id", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"result", 8u, false, INT64_C(0), INT64_C(3), false, INT64_C(0), INT64_C(0)},
    {"latch_gen", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_motion[] = {
    {"seq", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"command", 8u, false, INT64_C(0), INT64_C(255), true, INT64_C(0), INT64_C(4)},
    {"speed", 8u, false, INT64_C(0), INT64_C(255), true, INT64_C(0), INT64_C(60)},
    {"distance", 16u, false, INT64_C(0), INT64_C(65535), true, INT64_C(0), INT64_C(30000)},
};

static const rp_field_info_t fields_ack[] = {
    {"seq", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"result", 8u, false, INT64_C(0), INT64_C(6), false, INT64_C(0), INT64_C(0)},
    {"field", 8u, false, INT64_C(0), INT64_C(3), false, INT64_C(0), INT64_C(0)},
    {"queue_depth", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_status[] = {
    {"seq", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"state", 8u, false, INT64_C(0), INT64_C(2), false, INT64_C(0), INT64_C(0)},
    {"reason", 8u, false, INT64_C(0), INT64_C(5), false, INT64_C(0), INT64_C(0)},
    {"travel", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_stopped[] = {
    {"stop_id", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"distance_mm", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"duration_ms", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_fault[] = {
    {"code", 8u, false, INT64_C(1), INT64_C(8), false, INT64_C(0), INT64_C(0)},
    {"active", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"detail", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"latch_gen", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_heartbeat[] = {
    {"state", 3u, false, INT64_C(0), INT64_C(4), false, INT64_C(0), INT64_C(0)},
    {"stop_latched", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"handshake_ok", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"latch_stop", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"latch_watchdog", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"latch_fault", 1u, false, INT64_C(0), INT64_C(1), false, INT64_C(0), INT64_C(0)},
    {"fault_bits", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"queue_depth", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"boot_nonce", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"rx_errors", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"latch_gen", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_host_heartbeat[] = {
    {"counter", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_encoders[] = {
    {"t_ms", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"left", 24u, true, INT64_C(-8388608), INT64_C(8388607), false, INT64_C(0), INT64_C(0)},
    {"right", 24u, true, INT64_C(-8388608), INT64_C(8388607), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_wheel_speeds[] = {
    {"t_ms", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"left_mm_s", 12u, true, INT64_C(-2048), INT64_C(2047), false, INT64_C(0), INT64_C(0)},
    {"right_mm_s", 12u, true, INT64_C(-2048), INT64_C(2047), false, INT64_C(0), INT64_C(0)},
    {"left_target_mm_s", 12u, true, INT64_C(-2048), INT64_C(2047), false, INT64_C(0), INT64_C(0)},
    {"right_target_mm_s", 12u, true, INT64_C(-2048), INT64_C(2047), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_imu[] = {
    {"t_ms", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"yaw_rate_mrad_s", 16u, true, INT64_C(-32768), INT64_C(32767), false, INT64_C(0), INT64_C(0)},
    {"accel_x_mm_s2", 16u, true, INT64_C(-32768), INT64_C(32767), false, INT64_C(0), INT64_C(0)},
    {"accel_y_mm_s2", 16u, true, INT64_C(-32768), INT64_C(32767), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_pose[] = {
    {"x_mm", 20u, true, INT64_C(-524288), INT64_C(524287), false, INT64_C(0), INT64_C(0)},
    {"y_mm", 20u, true, INT64_C(-524288), INT64_C(524287), false, INT64_C(0), INT64_C(0)},
    {"yaw_ddeg", 12u, true, INT64_C(-1800), INT64_C(1800), false, INT64_C(0), INT64_C(0)},
    {"sigma_cm", 4u, false, INT64_C(0), INT64_C(15), false, INT64_C(0), INT64_C(0)},
    {"age_4ms", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_progress[] = {
    {"ended_seq", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"ended_state", 8u, false, INT64_C(0), INT64_C(2), false, INT64_C(0), INT64_C(0)},
    {"ended_reason", 8u, false, INT64_C(0), INT64_C(5), false, INT64_C(0), INT64_C(0)},
    {"ended_count", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"travel", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_hello[] = {
    {"protocol_version", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"schema_hash", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_ident[] = {
    {"protocol_version", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"firmware_major", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"firmware_minor", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"firmware_patch", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"schema_hash", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
    {"boot_nonce", 16u, false, INT64_C(0), INT64_C(65535), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_set_param[] = {
    {"param", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"value", 32u, true, INT64_C(-2147483648), INT64_C(2147483647), false, INT64_C(0), INT64_C(0)},
};

static const rp_field_info_t fields_param_value[] = {
    {"param", 8u, false, INT64_C(0), INT64_C(255), false, INT64_C(0), INT64_C(0)},
    {"result", 8u, false, INT64_C(0), INT64_C(2), false, INT64_C(0), INT64_C(0)},
    {"value", 32u, true, INT64_C(-2147483648), INT64_C(2147483647), false, INT64_C(0), INT64_C(0)},
};
#define RP_FIELDS(n, table) n, table
#endif

const rp_msg_info_t rp_msg_table[RP_MSG_COUNT] = {
    {RP_MSG_STOP, RP_MSG_STOP_LEN, RP_DIR_HOST_TO_CONTROLLER, "STOP", RP_FIELDS(2u, fields_stop)},
    {RP_MSG_STOP_ACK, RP_MSG_STOP_ACK_LEN, RP_DIR_CONTROLLER_TO_HOST, "STOP_ACK", RP_FIELDS(3u, fields_stop_ack)},
    {RP_MSG_CLEAR_STOP, RP_MSG_CLEAR_STOP_LEN, RP_DIR_HOST_TO_CONTROLLER, "CLEAR_STOP", RP_FIELDS(2u, fields_clear_stop)},
    {RP_MSG_CLEAR_ACK, RP_MSG_CLEAR_ACK_LEN, RP_DIR_CONTROLLER_TO_HOST, "CLEAR_ACK", RP_FIELDS(3u, fields_clear_ack)},
    {RP_MSG_MOTION, RP_MSG_MOTION_LEN, RP_DIR_HOST_TO_CONTROLLER, "MOTION", RP_FIELDS(4u, fields_motion)},
    {RP_MSG_ACK, RP_MSG_ACK_LEN, RP_DIR_CONTROLLER_TO_HOST, "ACK", RP_FIELDS(4u, fields_ack)},
    {RP_MSG_STATUS, RP_MSG_STATUS_LEN, RP_DIR_CONTROLLER_TO_HOST, "STATUS", RP_FIELDS(4u, fields_status)},
    {RP_MSG_STOPPED, RP_MSG_STOPPED_LEN, RP_DIR_CONTROLLER_TO_HOST, "STOPPED", RP_FIELDS(3u, fields_stopped)},
    {RP_MSG_FAULT, RP_MSG_FAULT_LEN, RP_DIR_CONTROLLER_TO_HOST, "FAULT", RP_FIELDS(4u, fields_fault)},
    {RP_MSG_HEARTBEAT, RP_MSG_HEARTBEAT_LEN, RP_DIR_CONTROLLER_TO_HOST, "HEARTBEAT", RP_FIELDS(11u, fields_heartbeat)},
    {RP_MSG_HOST_HEARTBEAT, RP_MSG_HOST_HEARTBEAT_LEN, RP_DIR_HOST_TO_CONTROLLER, "HOST_HEARTBEAT", RP_FIELDS(1u, fields_host_heartbeat)},
    {RP_MSG_ENCODERS, RP_MSG_ENCODERS_LEN, RP_DIR_CONTROLLER_TO_HOST, "ENCODERS", RP_FIELDS(3u, fields_encoders)},
    {RP_MSG_WHEEL_SPEEDS, RP_MSG_WHEEL_SPEEDS_LEN, RP_DIR_CONTROLLER_TO_HOST, "WHEEL_SPEEDS", RP_FIELDS(5u, fields_wheel_speeds)},
    {RP_MSG_IMU, RP_MSG_IMU_LEN, RP_DIR_CONTROLLER_TO_HOST, "IMU", RP_FIELDS(4u, fields_imu)},
    {RP_MSG_POSE, RP_MSG_POSE_LEN, RP_DIR_CONTROLLER_TO_HOST, "POSE", RP_FIELDS(5u, fields_pose)},
    {RP_MSG_PROGRESS, RP_MSG_PROGRESS_LEN, RP_DIR_CONTROLLER_TO_HOST, "PROGRESS", RP_FIELDS(5u, fields_progress)},
    {RP_MSG_HELLO, RP_MSG_HELLO_LEN, RP_DIR_HOST_TO_CONTROLLER, "HELLO", RP_FIELDS(2u, fields_hello)},
    {RP_MSG_IDENT, RP_MSG_IDENT_LEN, RP_DIR_CONTROLLER_TO_HOST, "IDENT", RP_FIELDS(6u, fields_ident)},
    {RP_MSG_SET_PARAM, RP_MSG_SET_PARAM_LEN, RP_DIR_HOST_TO_CONTROLLER, "SET_PARAM", RP_FIELDS(2u, fields_set_param)},
    {RP_MSG_PARAM_VALUE, RP_MSG_PARAM_VALUE_LEN, RP_DIR_CONTROLLER_TO_HOST, "PARAM_VALUE", RP_FIELDS(3u, fields_param_value)},
};

/* Index into rp_msg_table by message id; 0xFF: not in the protocol. */
static const uint8_t table_index[128] = {
    0, 1, 2, 3, 0xFF, 0xFF, 0xFF, 0xFF, 4, 5, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    6, 7, 8, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    9, 10, 11, 12, 13, 14, 15, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    16, 17, 18, 19, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
    0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
};

const rp_msg_info_t *rp_msg_info(uint32_t id)
{
    if (id >= 128u || table_index[id] == 0xFFu) {
        return NULL;
    }
    return &rp_msg_table[table_index[id]];
}

const rp_msg_info_t *rp_msg_by_name(const char *name)
{
    if (name == NULL) {
        return NULL;
    }
    for (size_t i = 0; i < RP_MSG_COUNT; ++i) {
        const char *a = rp_msg_table[i].name;
        const char *b = name;
        while (*a != '\0' && *a == *b) {
            ++a;
            ++b;
        }
        if (*a == *b) {
            return &rp_msg_table[i];
        }
    }
    return NULL;
}

int rp_msg_pack(const rp_msg_t *msg, bool strict, uint8_t *out, size_t cap)
{
    if (msg == NULL) {
        return RP_ERR_NULL;
    }
    switch (msg->id) {
    case RP_MSG_STOP:
        return rp_stop_pack(&msg->body.stop, strict, out, cap);
    case RP_MSG_STOP_ACK:
        return rp_stop_ack_pack(&msg->body.stop_ack, strict, out, cap);
    case RP_MSG_CLEAR_STOP:
        return rp_clear_stop_pack(&msg->body.clear_stop, strict, out, cap);
    case RP_MSG_CLEAR_ACK:
        return rp_clear_ack_pack(&msg->body.clear_ack, strict, out, cap);
    case RP_MSG_MOTION:
        return rp_motion_pack(&msg->body.motion, strict, out, cap);
    case RP_MSG_ACK:
        return rp_ack_pack(&msg->body.ack, strict, out, cap);
    case RP_MSG_STATUS:
        return rp_status_pack(&msg->body.status, strict, out, cap);
    case RP_MSG_STOPPED:
        return rp_stopped_pack(&msg->body.stopped, strict, out, cap);
    case RP_MSG_FAULT:
        return rp_fault_pack(&msg->body.fault, strict, out, cap);
    case RP_MSG_HEARTBEAT:
        return rp_heartbeat_pack(&msg->body.heartbeat, strict, out, cap);
    case RP_MSG_HOST_HEARTBEAT:
        return rp_host_heartbeat_pack(&msg->body.host_heartbeat, strict, out, cap);
    case RP_MSG_ENCODERS:
        return rp_encoders_pack(&msg->body.encoders, strict, out, cap);
    case RP_MSG_WHEEL_SPEEDS:
        return rp_wheel_speeds_pack(&msg->body.wheel_speeds, strict, out, cap);
    case RP_MSG_IMU:
        return rp_imu_pack(&msg->body.imu, strict, out, cap);
    case RP_MSG_POSE:
        return rp_pose_pack(&msg->body.pose, strict, out, cap);
    case RP_MSG_PROGRESS:
        return rp_progress_pack(&msg->body.progress, strict, out, cap);
    case RP_MSG_HELLO:
        return rp_hello_pack(&msg->body.hello, strict, out, cap);
    case RP_MSG_IDENT:
        return rp_ident_pack(&msg->body.ident, strict, out, cap);
    case RP_MSG_SET_PARAM:
        return rp_set_param_pack(&msg->body.set_param, strict, out, cap);
    case RP_MSG_PARAM_VALUE:
        return rp_param_value_pack(&msg->body.param_value, strict, out, cap);
    default:
        return RP_ERR_UNKNOWN_ID;
    }
}

int rp_msg_unpack(rp_msg_t *msg, uint32_t id, const uint8_t *payload, size_t len)
{
    if (msg == NULL) {
        return RP_ERR_NULL;
    }
    int rc;
    switch (id) {
    case RP_MSG_STOP:
        rc = rp_stop_unpack(&msg->body.stop, payload, len);
        break;
    case RP_MSG_STOP_ACK:
        rc = rp_stop_ack_unpack(&msg->body.stop_ack, payload, len);
        break;
    case RP_MSG_CLEAR_STOP:
        rc = rp_clear_stop_unpack(&msg->body.clear_stop, payload, len);
        break;
    case RP_MSG_CLEAR_ACK:
        rc = rp_clear_ack_unpack(&msg->body.clear_ack, payload, len);
        break;
    case RP_MSG_MOTION:
        rc = rp_motion_unpack(&msg->body.motion, payload, len);
        break;
    case RP_MSG_ACK:
        rc = rp_ack_unpack(&msg->body.ack, payload, len);
        break;
    case RP_MSG_STATUS:
        rc = rp_status_unpack(&msg->body.status, payload, len);
        break;
    case RP_MSG_STOPPED:
        rc = rp_stopped_unpack(&msg->body.stopped, payload, len);
        break;
    case RP_MSG_FAULT:
        rc = rp_fault_unpack(&msg->body.fault, payload, len);
        break;
    case RP_MSG_HEARTBEAT:
        rc = rp_heartbeat_unpack(&msg->body.heartbeat, payload, len);
        break;
    case RP_MSG_HOST_HEARTBEAT:
        rc = rp_host_heartbeat_unpack(&msg->body.host_heartbeat, payload, len);
        break;
    case RP_MSG_ENCODERS:
        rc = rp_encoders_unpack(&msg->body.encoders, payload, len);
        break;
    case RP_MSG_WHEEL_SPEEDS:
        rc = rp_wheel_speeds_unpack(&msg->body.wheel_speeds, payload, len);
        break;
    case RP_MSG_IMU:
        rc = rp_imu_unpack(&msg->body.imu, payload, len);
        break;
    case RP_MSG_POSE:
        rc = rp_pose_unpack(&msg->body.pose, payload, len);
        break;
    case RP_MSG_PROGRESS:
        rc = rp_progress_unpack(&msg->body.progress, payload, len);
        break;
    case RP_MSG_HELLO:
        rc = rp_hello_unpack(&msg->body.hello, payload, len);
        break;
    case RP_MSG_IDENT:
        rc = rp_ident_unpack(&msg->body.ident, payload, len);
        break;
    case RP_MSG_SET_PARAM:
        rc = rp_set_param_unpack(&msg->body.set_param, payload, len);
        break;
    case RP_MSG_PARAM_VALUE:
        rc = rp_param_value_unpack(&msg->body.param_value, payload, len);
        break;
    default:
        return RP_ERR_UNKNOWN_ID;
    }
    if (rc == RP_OK) {
        msg->id = (uint8_t)id;
    }
    return rc;
}

int rp_msg_get_field(const rp_msg_t *msg, unsigned index, int64_t *value)
{
    if (msg == NULL || value == NULL) {
        return RP_ERR_NULL;
    }
    switch (msg->id) {
    case RP_MSG_STOP:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.stop.stop_id; return RP_OK;
        case 1u: *value = (int64_t)msg->body.stop.source; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STOP_ACK:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.stop_ack.stop_id; return RP_OK;
        case 1u: *value = (int64_t)msg->body.stop_ack.state; return RP_OK;
        case 2u: *value = (int64_t)msg->body.stop_ack.latch_gen; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_CLEAR_STOP:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.clear_stop.stop_id; return RP_OK;
        case 1u: *value = (int64_t)msg->body.clear_stop.latch_gen; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_CLEAR_ACK:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.clear_ack.stop_id; return RP_OK;
        case 1u: *value = (int64_t)msg->body.clear_ack.result; return RP_OK;
        case 2u: *value = (int64_t)msg->body.clear_ack.latch_gen; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_MOTION:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.motion.seq; return RP_OK;
        case 1u: *value = (int64_t)msg->body.motion.command; return RP_OK;
        case 2u: *value = (int64_t)msg->body.motion.speed; return RP_OK;
        case 3u: *value = (int64_t)msg->body.motion.distance; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_ACK:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.ack.seq; return RP_OK;
        case 1u: *value = (int64_t)msg->body.ack.result; return RP_OK;
        case 2u: *value = (int64_t)msg->body.ack.field; return RP_OK;
        case 3u: *value = (int64_t)msg->body.ack.queue_depth; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STATUS:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.status.seq; return RP_OK;
        case 1u: *value = (int64_t)msg->body.status.state; return RP_OK;
        case 2u: *value = (int64_t)msg->body.status.reason; return RP_OK;
        case 3u: *value = (int64_t)msg->body.status.travel; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STOPPED:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.stopped.stop_id; return RP_OK;
        case 1u: *value = (int64_t)msg->body.stopped.distance_mm; return RP_OK;
        case 2u: *value = (int64_t)msg->body.stopped.duration_ms; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_FAULT:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.fault.code; return RP_OK;
        case 1u: *value = (int64_t)msg->body.fault.active; return RP_OK;
        case 2u: *value = (int64_t)msg->body.fault.detail; return RP_OK;
        case 3u: *value = (int64_t)msg->body.fault.latch_gen; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HEARTBEAT:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.heartbeat.state; return RP_OK;
        case 1u: *value = (int64_t)msg->body.heartbeat.stop_latched; return RP_OK;
        case 2u: *value = (int64_t)msg->body.heartbeat.handshake_ok; return RP_OK;
        case 3u: *value = (int64_t)msg->body.heartbeat.latch_stop; return RP_OK;
        case 4u: *value = (int64_t)msg->body.heartbeat.latch_watchdog; return RP_OK;
        case 5u: *value = (int64_t)msg->body.heartbeat.latch_fault; return RP_OK;
        case 6u: *value = (int64_t)msg->body.heartbeat.fault_bits; return RP_OK;
        case 7u: *value = (int64_t)msg->body.heartbeat.queue_depth; return RP_OK;
        case 8u: *value = (int64_t)msg->body.heartbeat.boot_nonce; return RP_OK;
        case 9u: *value = (int64_t)msg->body.heartbeat.rx_errors; return RP_OK;
        case 10u: *value = (int64_t)msg->body.heartbeat.latch_gen; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HOST_HEARTBEAT:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.host_heartbeat.counter; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_ENCODERS:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.encoders.t_ms; return RP_OK;
        case 1u: *value = (int64_t)msg->body.encoders.left; return RP_OK;
        case 2u: *value = (int64_t)msg->body.encoders.right; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_WHEEL_SPEEDS:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.wheel_speeds.t_ms; return RP_OK;
        case 1u: *value = (int64_t)msg->body.wheel_speeds.left_mm_s; return RP_OK;
        case 2u: *value = (int64_t)msg->body.wheel_speeds.right_mm_s; return RP_OK;
        case 3u: *value = (int64_t)msg->body.wheel_speeds.left_target_mm_s; return RP_OK;
        case 4u: *value = (int64_t)msg->body.wheel_speeds.right_target_mm_s; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_IMU:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.imu.t_ms; return RP_OK;
        case 1u: *value = (int64_t)msg->body.imu.yaw_rate_mrad_s; return RP_OK;
        case 2u: *value = (int64_t)msg->body.imu.accel_x_mm_s2; return RP_OK;
        case 3u: *value = (int64_t)msg->body.imu.accel_y_mm_s2; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_POSE:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.pose.x_mm; return RP_OK;
        case 1u: *value = (int64_t)msg->body.pose.y_mm; return RP_OK;
        case 2u: *value = (int64_t)msg->body.pose.yaw_ddeg; return RP_OK;
        case 3u: *value = (int64_t)msg->body.pose.sigma_cm; return RP_OK;
        case 4u: *value = (int64_t)msg->body.pose.age_4ms; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_PROGRESS:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.progress.ended_seq; return RP_OK;
        case 1u: *value = (int64_t)msg->body.progress.ended_state; return RP_OK;
        case 2u: *value = (int64_t)msg->body.progress.ended_reason; return RP_OK;
        case 3u: *value = (int64_t)msg->body.progress.ended_count; return RP_OK;
        case 4u: *value = (int64_t)msg->body.progress.travel; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HELLO:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.hello.protocol_version; return RP_OK;
        case 1u: *value = (int64_t)msg->body.hello.schema_hash; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_IDENT:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.ident.protocol_version; return RP_OK;
        case 1u: *value = (int64_t)msg->body.ident.firmware_major; return RP_OK;
        case 2u: *value = (int64_t)msg->body.ident.firmware_minor; return RP_OK;
        case 3u: *value = (int64_t)msg->body.ident.firmware_patch; return RP_OK;
        case 4u: *value = (int64_t)msg->body.ident.schema_hash; return RP_OK;
        case 5u: *value = (int64_t)msg->body.ident.boot_nonce; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_SET_PARAM:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.set_param.param; return RP_OK;
        case 1u: *value = (int64_t)msg->body.set_param.value; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_PARAM_VALUE:
        switch (index) {
        case 0u: *value = (int64_t)msg->body.param_value.param; return RP_OK;
        case 1u: *value = (int64_t)msg->body.param_value.result; return RP_OK;
        case 2u: *value = (int64_t)msg->body.param_value.value; return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    default:
        return RP_ERR_UNKNOWN_ID;
    }
}

int rp_msg_set_field(rp_msg_t *msg, unsigned index, int64_t value)
{
    if (msg == NULL) {
        return RP_ERR_NULL;
    }
    switch (msg->id) {
    case RP_MSG_STOP:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.stop.stop_id = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.stop.source = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STOP_ACK:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.stop_ack.stop_id = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.stop_ack.state = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.stop_ack.latch_gen = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_CLEAR_STOP:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.clear_stop.stop_id = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.clear_stop.latch_gen = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_CLEAR_ACK:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.clear_ack.stop_id = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.clear_ack.result = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.clear_ack.latch_gen = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_MOTION:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.motion.seq = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.motion.command = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.motion.speed = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.motion.distance = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_ACK:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.ack.seq = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.ack.result = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.ack.field = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.ack.queue_depth = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STATUS:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.status.seq = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.status.state = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.status.reason = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.status.travel = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_STOPPED:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.stopped.stop_id = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.stopped.distance_mm = (uint16_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.stopped.duration_ms = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_FAULT:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.fault.code = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.fault.active = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.fault.detail = (uint16_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.fault.latch_gen = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HEARTBEAT:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.heartbeat.state = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.heartbeat.stop_latched = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.heartbeat.handshake_ok = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.heartbeat.latch_stop = (uint8_t)value;
            return RP_OK;
        case 4u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(4);
            }
            msg->body.heartbeat.latch_watchdog = (uint8_t)value;
            return RP_OK;
        case 5u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(5);
            }
            msg->body.heartbeat.latch_fault = (uint8_t)value;
            return RP_OK;
        case 6u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(6);
            }
            msg->body.heartbeat.fault_bits = (uint8_t)value;
            return RP_OK;
        case 7u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(7);
            }
            msg->body.heartbeat.queue_depth = (uint8_t)value;
            return RP_OK;
        case 8u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(8);
            }
            msg->body.heartbeat.boot_nonce = (uint16_t)value;
            return RP_OK;
        case 9u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(9);
            }
            msg->body.heartbeat.rx_errors = (uint16_t)value;
            return RP_OK;
        case 10u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(10);
            }
            msg->body.heartbeat.latch_gen = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HOST_HEARTBEAT:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.host_heartbeat.counter = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_ENCODERS:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.encoders.t_ms = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.encoders.left = (int32_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.encoders.right = (int32_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_WHEEL_SPEEDS:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.wheel_speeds.t_ms = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.wheel_speeds.left_mm_s = (int16_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.wheel_speeds.right_mm_s = (int16_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.wheel_speeds.left_target_mm_s = (int16_t)value;
            return RP_OK;
        case 4u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(4);
            }
            msg->body.wheel_speeds.right_target_mm_s = (int16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_IMU:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.imu.t_ms = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.imu.yaw_rate_mrad_s = (int16_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.imu.accel_x_mm_s2 = (int16_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.imu.accel_y_mm_s2 = (int16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_POSE:
        switch (index) {
        case 0u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.pose.x_mm = (int32_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.pose.y_mm = (int32_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(-32768) || value > INT64_C(32767)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.pose.yaw_ddeg = (int16_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.pose.sigma_cm = (uint8_t)value;
            return RP_OK;
        case 4u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(4);
            }
            msg->body.pose.age_4ms = (uint8_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_PROGRESS:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.progress.ended_seq = (uint16_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.progress.ended_state = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.progress.ended_reason = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.progress.ended_count = (uint16_t)value;
            return RP_OK;
        case 4u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(4);
            }
            msg->body.progress.travel = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_HELLO:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.hello.protocol_version = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.hello.schema_hash = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_IDENT:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.ident.protocol_version = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.ident.firmware_major = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.ident.firmware_minor = (uint8_t)value;
            return RP_OK;
        case 3u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(3);
            }
            msg->body.ident.firmware_patch = (uint8_t)value;
            return RP_OK;
        case 4u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(4);
            }
            msg->body.ident.schema_hash = (uint16_t)value;
            return RP_OK;
        case 5u:
            if (value < INT64_C(0) || value > INT64_C(65535)) {
                return RP_ERR_FIELD(5);
            }
            msg->body.ident.boot_nonce = (uint16_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_SET_PARAM:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.set_param.param = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.set_param.value = (int32_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    case RP_MSG_PARAM_VALUE:
        switch (index) {
        case 0u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(0);
            }
            msg->body.param_value.param = (uint8_t)value;
            return RP_OK;
        case 1u:
            if (value < INT64_C(0) || value > INT64_C(255)) {
                return RP_ERR_FIELD(1);
            }
            msg->body.param_value.result = (uint8_t)value;
            return RP_OK;
        case 2u:
            if (value < INT64_C(-2147483648) || value > INT64_C(2147483647)) {
                return RP_ERR_FIELD(2);
            }
            msg->body.param_value.value = (int32_t)value;
            return RP_OK;
        default: return RP_ERR_FIELD(index);
        }
    default:
        return RP_ERR_UNKNOWN_ID;
    }
}
