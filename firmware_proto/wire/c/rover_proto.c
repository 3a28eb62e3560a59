/**
 * @file rover_proto.c
 * @brief Serial framing, COBS, CRC-16, stream decoder and CAN mapping (rover_proto.h).
 *
 * Hand-written; the message layouts come from the generated rover_msgs.c. The decoder
 * mirrors firmware_proto/wire/framing.py FrameDecoder rule for rule; comments name the rule.
 */
#include "rover_proto.h"

/* ------------------------------------------------------------------ CRC-16 */

uint16_t rp_crc16_update(uint16_t crc, const uint8_t *data, size_t len)
{
    if (data == NULL) {
        return crc;
    }
    for (size_t i = 0; i < len; ++i) {
        crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)data[i] << 8));
        for (unsigned bit = 0; bit < 8u; ++bit) {
            if ((crc & 0x8000u) != 0u) {
                crc = (uint16_t)((uint16_t)(crc << 1) ^ 0x1021u);
            } else {
                crc = (uint16_t)(crc << 1);
            }
        }
    }
    return crc;
}

uint16_t rp_crc16(const uint8_t *data, size_t len)
{
    return rp_crc16_update((uint16_t)RP_CRC16_INIT, data, len);
}

/* ------------------------------------------------------------------ COBS */

int rp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    if (out == NULL || (in == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    /* Same block structure as firmware_proto/wire/cobs.py: every zero-separated run of the
     * input becomes 0xFF blocks of 254 bytes while at least 254 remain, then one block
     * (length + 1) with the rest, which may be empty. */
    size_t o = 0;
    size_t i = 0;
    for (;;) {
        size_t end = i;
        while (end < len && in[end] != 0u) {
            ++end;
        }
        size_t rest = end - i;
        while (rest >= 254u) {
            if (cap - o < 255u) {
                return RP_ERR_BUFFER;
            }
            out[o++] = 0xFFu;
            for (size_t k = 0; k < 254u; ++k) {
                out[o++] = in[i++];
            }
            rest -= 254u;
        }
        if (cap - o < rest + 1u) {
            return RP_ERR_BUFFER;
        }
        out[o++] = (uint8_t)(rest + 1u);
        while (i < end) {
            out[o++] = in[i++];
        }
        if (end >= len) {
            break;
        }
        i = end + 1u; /* skip the zero that ended this run */
    }
    if (o > (size_t)0x7FFFFFFF) {
        return RP_ERR_BUFFER;
    }
    return (int)o;
}

int rp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    if (out == NULL || (in == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    size_t i = 0;
    size_t o = 0;
    while (i < len) {
        const uint8_t code = in[i];
        if (code == 0u || (size_t)code > len - i) {
            return RP_ERR_FRAMING;
        }
        const size_t end = i + code;
        ++i;
        /* Forward byte copy: o <= i always holds, so decoding in place is safe. */
        while (i < end) {
            if (o >= cap) {
                return RP_ERR_BUFFER;
            }
            out[o++] = in[i++];
        }
        if (code != 0xFFu && i < len) {
            if (o >= cap) {
                return RP_ERR_BUFFER;
            }
            out[o++] = 0u;
        }
    }
    if (o > (size_t)0x7FFFFFFF) {
        return RP_ERR_BUFFER;
    }
    return (int)o;
}

/* ------------------------------------------------------------------ serial encode */

int rp_encode_frame(uint8_t id, uint8_t seq, const uint8_t *payload, size_t len, uint8_t *out,
                    size_t cap)
{
    if (out == NULL || (payload == NULL && len > 0u)) {
        return RP_ERR_NULL;
    }
    if (len > RP_MAX_PAYLOAD_BYTES) {
        return RP_ERR_LENGTH;
    }
    uint8_t raw[RP_MAX_FRAME_BYTES];
    size_t n = 0;
    raw[n++] = id;
    raw[n++] = seq;
    for (size_t k = 0; k < len; ++k) {
        raw[n++] = payload[k];
    }
    const uint16_t crc = rp_crc16(raw, n);
    raw[n++] = (uint8_t)(crc >> 8);
    raw[n++] = (uint8_t)(crc & 0xFFu);
    if (cap < 2u) {
        return RP_ERR_BUFFER;
    }
    out[0] = RP_DELIMITER;
    const int stuffed = rp_cobs_encode(raw, n, out + 1, cap - 2u);
    if (stuffed < 0) {
        return stuffed;
    }
    out[1u + (size_t)stuffed] = RP_DELIMITER;
    return stuffed + 2;
}

int rp_encode_message(const rp_msg_t *msg, uint8_t seq, bool strict, uint8_t *out, size_t cap)
{
    uint8_t payload[RP_MAX_PAYLOAD_BYTES];
    const int n = rp_msg_pack(msg, strict, payload, sizeof payload);
    if (n < 0) {
        return n;
    }
    return rp_encode_frame(msg->id, seq, payload, (size_t)n, out, cap);
}

/* ------------------------------------------------------------------ counters */

uint32_t rp_counters_rejected(const rp_counters_t *c)
{
    if (c == NULL) {
        return 0u;
    }
    return c->framing + c->oversize + c->crc + c->unknown_id + c->bad_length + c->out_of_range +
           c->not_classic;
}

static void counters_zero(rp_counters_t *c)
{
    c->frames = 0u;
    c->bytes = 0u;
    c->dropped_bytes = 0u;
    c->framing = 0u;
    c->oversize = 0u;
    c->crc = 0u;
    c->unknown_id = 0u;
    c->bad_length = 0u;
    c->out_of_range = 0u;
    c->lost = 0u;
    c->not_classic = 0u;
}

/* ------------------------------------------------------------------ serial decode */

void rp_decoder_reset(rp_decoder_t *dec)
{
    if (dec == NULL) {
        return;
    }
    dec->run = 0u;
    dec->discarding = false;
    dec->have_seq = false;
    dec->last_seq = 0u;
}

void rp_decoder_init(rp_decoder_t *dec)
{
    if (dec == NULL) {
        return;
    }
    counters_zero(&dec->counters);
    for (size_t k = 0; k < sizeof dec->buf; ++k) {
        dec->buf[k] = 0u;
    }
    rp_decoder_reset(dec);
}

/* FrameDecoder._reject: one reason counter, and the run plus its delimiter. */
static void reject(rp_decoder_t *dec, uint32_t *reason)
{
    *reason += 1u;
    dec->counters.dropped_bytes += (uint32_t)(dec->run + 1u);
}

/* FrameDecoder._drop_run: a run longer than any frame and still open. */
static void drop_run(rp_decoder_t *dec)
{
    if (!dec->discarding) {
        dec->counters.oversize += 1u;
        dec->discarding = true;
    }
    dec->counters.dropped_bytes += (uint32_t)dec->run;
    dec->run = 0u;
}

/* FrameDecoder._decode of the run in dec->buf (run <= RP_MAX_ENCODED_BYTES, not empty). */
static bool decode_run(rp_decoder_t *dec, rp_frame_t *frame)
{
    rp_counters_t *c = &dec->counters;
    uint8_t raw[RP_MAX_FRAME_BYTES];
    const int n = rp_cobs_decode(dec->buf, dec->run, raw, sizeof raw);
    if (n < (int)RP_MIN_FRAME_BYTES) {
        reject(dec, &c->framing);
        return false;
    }
    if (rp_crc16(raw, (size_t)n) != 0u) {
        /* The CRC is sent big-endian, so a good frame's CRC over itself is zero. */
        reject(dec, &c->crc);
        return false;
    }
    const rp_msg_info_t *info = rp_msg_info(raw[0]);
    if (info == NULL) {
        reject(dec, &c->unknown_id);
        return false;
    }
    if ((size_t)n != (size_t)info->length + RP_MIN_FRAME_BYTES) {
        reject(dec, &c->bad_length);
        return false;
    }
    rp_msg_t msg;
    if (rp_msg_unpack(&msg, raw[0], raw + RP_FRAME_HEADER_BYTES, info->length) != RP_OK) {
        reject(dec, &c->out_of_range);
        return false;
    }
    const uint8_t seq = raw[1];
    if (dec->have_seq) {
        c->lost += (uint32_t)(uint8_t)(seq - dec->last_seq - 1u);
    }
    dec->have_seq = true;
    dec->last_seq = seq;
    c->frames += 1u;
    frame->seq = seq;
    frame->msg = msg;
    return true;
}

bool rp_decoder_feed(rp_decoder_t *dec, const uint8_t **data, size_t *len, rp_frame_t *frame)
{
    if (dec == NULL || data == NULL || len == NULL || frame == NULL ||
        (*data == NULL && *len > 0u)) {
        return false;
    }
    const uint8_t *p = *data;
    size_t n = *len;
    bool got = false;
    while (n > 0u && !got) {
        const uint8_t byte = *p++;
        --n;
        dec->counters.bytes += 1u;
        if (byte != RP_DELIMITER) {
            if (dec->run < sizeof dec->buf) {
                dec->buf[dec->run] = byte;
            }
            dec->run += 1u;
            continue;
        }
        if (dec->discarding) {
            /* The end of a run already counted as oversize, and its closing delimiter, so
             * that the count does not depend on how the stream was chunked. */
            dec->discarding = false;
            dec->counters.dropped_bytes += (uint32_t)(dec->run + 1u);
        } else if (dec->run > RP_MAX_ENCODED_BYTES) {
            reject(dec, &dec->counters.oversize);
        } else if (dec->run > 0u) {
            got = decode_run(dec, frame);
        }
        dec->run = 0u;
    }
    *data = p;
    *len = n;
    if (n == 0u && dec->run > RP_MAX_ENCODED_BYTES) {
        /* End of the chunk: like FrameDecoder.feed, never keep more than a frame's worth. */
        drop_run(dec);
    }
    return got;
}

bool rp_decoder_put(rp_decoder_t *dec, uint8_t byte, rp_frame_t *frame)
{
    const uint8_t *p = &byte;
    size_t n = 1u;
    return rp_decoder_feed(dec, &p, &n, frame);
}

/* ------------------------------------------------------------------ CAN */

int rp_can_id(uint32_t msg_id, uint32_t node)
{
    if (node > RP_CAN_MAX_NODE) {
        return RP_ERR_NODE;
    }
    if (msg_id > (RP_CAN_MAX_ID >> RP_CAN_NODE_BITS)) {
        return RP_ERR_UNKNOWN_ID;
    }
    return (int)((msg_id << RP_CAN_NODE_BITS) | node);
}

int rp_can_encode(const rp_msg_t *msg, uint32_t node, bool strict, uint32_t *can_id,
                  uint8_t data[RP_MAX_PAYLOAD_BYTES])
{
    if (msg == NULL || can_id == NULL || data == NULL) {
        return RP_ERR_NULL;
    }
    const rp_msg_info_t *info = rp_msg_info(msg->id);
    if (info == NULL) {
        return RP_ERR_UNKNOWN_ID;
    }
    if (node == RP_BROADCAST_NODE && info->direction != RP_DIR_HOST_TO_CONTROLLER) {
        return RP_ERR_BROADCAST;
    }
    const int id = rp_can_id(msg->id, node);
    if (id < 0) {
        return id;
    }
    const int n = rp_msg_pack(msg, strict, data, RP_MAX_PAYLOAD_BYTES);
    if (n < 0) {
        return n;
    }
    *can_id = (uint32_t)id;
    return n;
}

void rp_can_decoder_init(rp_can_decoder_t *dec)
{
    if (dec != NULL) {
        counters_zero(&dec->counters);
    }
}

bool rp_can_decode(rp_can_decoder_t *dec, uint32_t can_id, bool is_extended, bool is_remote,
                   const uint8_t *data, size_t len, rp_can_frame_t *frame)
{
    if (dec == NULL || frame == NULL || (data == NULL && len > 0u)) {
        return false;
    }
    rp_counters_t *c = &dec->counters;
    if (is_extended || is_remote || can_id > RP_CAN_MAX_ID) {
        c->not_classic += 1u;
        return false;
    }
    const uint32_t msg_id = RP_CAN_MSG_ID(can_id);
    const rp_msg_info_t *info = rp_msg_info(msg_id);
    if (info == NULL) {
        c->unknown_id += 1u;
        return false;
    }
    if (len != info->length) {
        c->bad_length += 1u;
        return false;
    }
    rp_msg_t msg;
    if (rp_msg_unpack(&msg, msg_id, data, len) != RP_OK) {
        c->out_of_range += 1u;
        return false;
    }
    c->frames += 1u;
    frame->node = (uint8_t)RP_CAN_NODE(can_id);
    frame->msg = msg;
    return true;
}
