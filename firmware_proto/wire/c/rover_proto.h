/**
 * @file rover_proto.h
 * @brief Serial framing, COBS, CRC-16, stream decoder and CAN mapping of the rover
 *        motor-controller protocol: the C reference codec for the firmware.
 *
 * Serial frame on the wire (docs/protocol.md, "Serial framing"):
 *
 *     0x00 | COBS( id:u8 | seq:u8 | payload:0..8 bytes | crc:u16 big-endian ) | 0x00
 *
 * with crc = CRC-16/CCITT-FALSE over id, seq and payload. On CAN the identifier is
 * id << 4 | node and the data are the payload (rover_msgs.h packs it).
 *
 * Properties: C99, no heap, no stdio, no floating point, no recursion, no libc calls,
 * fixed buffers whose sizes are compile-time constants. Every function is reentrant;
 * a decoder object belongs to one caller (protect it yourself if an ISR and a task
 * share it). Decoders never fail on bad input: they drop it and count it in
 * rp_counters_t, exactly as the Python reference (firmware_proto.wire.framing.FrameDecoder,
 * firmware_proto.wire.canmap.CanDecoder) does, counter for counter; the shared test vectors
 * under firmware_proto/wire/vectors/ pin that.
 *
 * Counters are uint32_t and wrap after 2^32 events.
 */
#ifndef ROVER_PROTO_H
#define ROVER_PROTO_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "rover_msgs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------ sizes */

/** Bytes before the payload in an unstuffed frame: id, seq. */
#define RP_FRAME_HEADER_BYTES 2u
/** Bytes after the payload in an unstuffed frame: the CRC. */
#define RP_FRAME_CRC_BYTES 2u
/** Smallest unstuffed frame (empty payload): 4 bytes. */
#define RP_MIN_FRAME_BYTES (RP_FRAME_HEADER_BYTES + RP_FRAME_CRC_BYTES)
/** Largest unstuffed frame: id, seq, 8-byte payload, CRC (12 bytes). */
#define RP_MAX_FRAME_BYTES (RP_FRAME_HEADER_BYTES + RP_MAX_PAYLOAD_BYTES + RP_FRAME_CRC_BYTES)
/** Largest COBS output for n input bytes (delimiters excluded). */
#define RP_COBS_MAX_ENCODED(n) ((n) + (n) / 254u + 1u)
/** Longest run between two delimiters that can be a frame (13 bytes). */
#define RP_MAX_ENCODED_BYTES RP_COBS_MAX_ENCODED(RP_MAX_FRAME_BYTES)
/** Largest frame on the wire with both delimiters (15 bytes): size of a TX buffer. */
#define RP_MAX_WIRE_BYTES (RP_MAX_ENCODED_BYTES + 2u)

/* ------------------------------------------------------------------ CRC-16 */

/** Initial value of CRC-16/CCITT-FALSE. */
#define RP_CRC16_INIT 0xFFFFu

/**
 * Continue a CRC-16/CCITT-FALSE (poly 0x1021, no reflection, no final XOR).
 * @param crc  running value, RP_CRC16_INIT for a new computation.
 * @param data bytes to add; may be NULL only if len is 0.
 * @param len  number of bytes.
 * @return the updated CRC. rp_crc16_update(RP_CRC16_INIT, "123456789", 9) == 0x29B1.
 */
uint16_t rp_crc16_update(uint16_t crc, const uint8_t *data, size_t len);

/** CRC-16/CCITT-FALSE of data[0..len). Same as rp_crc16_update(RP_CRC16_INIT, ...). */
uint16_t rp_crc16(const uint8_t *data, size_t len);

/* ------------------------------------------------------------------ COBS */

/**
 * COBS-encode in[0..len) into out (no delimiters are added); the output has no zero.
 * @param cap capacity of out; RP_COBS_MAX_ENCODED(len) always suffices.
 * @return output length (>= 1), or RP_ERR_NULL, or RP_ERR_BUFFER if cap is too small
 *         (out may then hold a partial result). in and out must not overlap.
 */
int rp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/**
 * Decode one COBS block in[0..len) (no delimiters) into out.
 * @param cap capacity of out; len - 1 always suffices (len >= 1).
 * @return decoded length, RP_ERR_FRAMING if a code byte is zero or runs past the end
 *         (no encoder produces that; data bytes are copied as they are, as cobs.py does),
 *         RP_ERR_BUFFER if cap is too small, RP_ERR_NULL. out may equal in (decoding in
 *         place is safe); other overlaps are not.
 */
int rp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/* ------------------------------------------------------------------ serial encode */

/**
 * Frame raw payload bytes: 0x00 | COBS(id, seq, payload, crc) | 0x00. No field checks;
 * use rp_encode_message for messages.
 * @param payload may be NULL only if len is 0; len <= RP_MAX_PAYLOAD_BYTES.
 * @param out     buffer of cap bytes; RP_MAX_WIRE_BYTES always suffices.
 * @return wire length, or RP_ERR_LENGTH (len too big), RP_ERR_BUFFER, RP_ERR_NULL.
 */
int rp_encode_frame(uint8_t id, uint8_t seq, const uint8_t *payload, size_t len, uint8_t *out,
                    size_t cap);

/**
 * Pack and frame one message.
 * @param strict also enforce semantic limits (see rp_msg_pack).
 * @return wire length, or the negative code of rp_msg_pack (RP_ERR_FIELD(i) names the
 *         field) or rp_encode_frame.
 */
int rp_encode_message(const rp_msg_t *msg, uint8_t seq, bool strict, uint8_t *out, size_t cap);

/* ------------------------------------------------------------------ counters */

/** What a decoder received and dropped, by reason; mirrors Python's RxCounters. */
typedef struct {
    uint32_t frames;        /**< valid frames delivered */
    uint32_t bytes;         /**< bytes fed (serial only) */
    uint32_t dropped_bytes; /**< bytes discarded in rejected frames or garbage (serial) */
    uint32_t framing;       /**< COBS broken or fewer than 4 bytes (serial) */
    uint32_t oversize;      /**< more than RP_MAX_ENCODED_BYTES between delimiters (serial) */
    uint32_t crc;           /**< CRC mismatch (serial) */
    uint32_t unknown_id;    /**< message id not in the protocol */
    uint32_t bad_length;    /**< payload length differs from the message's */
    uint32_t out_of_range;  /**< a field outside its wire range */
    uint32_t lost;          /**< frames missing by the sender's frame counter (serial) */
    uint32_t not_classic;   /**< extended-id, remote or > 11-bit CAN frames (CAN) */
} rp_counters_t;

/** Frames or garbage runs dropped for any reason (the sum of the reason counters). */
uint32_t rp_counters_rejected(const rp_counters_t *counters);

/* ------------------------------------------------------------------ serial decode */

/** One decoded serial frame. */
typedef struct {
    uint8_t seq;  /**< sender's frame counter */
    rp_msg_t msg; /**< the message (msg.id is the frame id) */
} rp_frame_t;

/**
 * Incremental serial stream decoder: the counters, a RP_MAX_ENCODED_BYTES buffer and a
 * few words of state (80 bytes on LP64, 68 on 32-bit targets). Treat as opaque except
 * counters. Initialise with rp_decoder_init.
 */
typedef struct {
    rp_counters_t counters;           /**< read freely; only ever grows */
    uint8_t buf[RP_MAX_ENCODED_BYTES]; /**< bytes since the last delimiter (first ones) */
    size_t run;                       /**< bytes since the last delimiter (may exceed buf) */
    bool discarding;                  /**< inside a run already counted as oversize */
    bool have_seq;                    /**< last_seq is valid */
    uint8_t last_seq;                 /**< frame counter of the last valid frame */
} rp_decoder_t;

/** Zero the counters and forget any partial frame. */
void rp_decoder_init(rp_decoder_t *dec);

/**
 * Forget the partial frame and the frame counter (e.g. after a reconnect); the counters
 * keep their values. Mirrors FrameDecoder.reset().
 */
void rp_decoder_reset(rp_decoder_t *dec);

/**
 * Feed one chunk of received bytes; deliver the next complete valid frame.
 *
 * Consumes bytes from *data (advancing *data and decreasing *len) up to and including
 * the delimiter that completes a valid frame, stores it in *frame and returns true; or
 * consumes all bytes and returns false. Call it again with the same data/len until it
 * returns false: the chunk is then fully processed, exactly as one call of the Python
 * FrameDecoder.feed(chunk) (counters included: a run of more than RP_MAX_ENCODED_BYTES
 * bytes still open at the end of a chunk is dropped as oversize there).
 *
 *     const uint8_t *p = rx; size_t n = rx_len; rp_frame_t f;
 *     while (rp_decoder_feed(&dec, &p, &n, &f)) { handle(&f); }
 *
 * Invalid frames are dropped and counted, never delivered. *frame is only written
 * when true is returned. Any chunk size works, including 0 and 1.
 *
 * @return true if *frame holds a new valid frame; false when the chunk is used up, or
 *         at once, consuming nothing, if an argument is NULL (*data only if *len > 0).
 */
bool rp_decoder_feed(rp_decoder_t *dec, const uint8_t **data, size_t *len, rp_frame_t *frame);

/** Feed a single byte (a UART RX interrupt); same as rp_decoder_feed with a 1-byte chunk. */
bool rp_decoder_put(rp_decoder_t *dec, uint8_t byte, rp_frame_t *frame);

/* ------------------------------------------------------------------ CAN */

/** Largest node id: RP_CAN_NODE_BITS bits (15). */
#define RP_CAN_MAX_NODE ((1u << RP_CAN_NODE_BITS) - 1u)
/** Largest 11-bit identifier. */
#define RP_CAN_MAX_ID 0x7FFu
/** Message id of an 11-bit CAN identifier. */
#define RP_CAN_MSG_ID(can_id) ((uint32_t)(can_id) >> RP_CAN_NODE_BITS)
/** Node id of an 11-bit CAN identifier. */
#define RP_CAN_NODE(can_id) ((uint32_t)(can_id) & RP_CAN_MAX_NODE)

/**
 * 11-bit identifier of message msg_id for node: msg_id << 4 | node.
 * @return the identifier, or RP_ERR_NODE (node > 15), RP_ERR_UNKNOWN_ID (msg_id > 127).
 */
int rp_can_id(uint32_t msg_id, uint32_t node);

/**
 * Identifier and data of one message for a node.
 * @param node  0..15; 0 (broadcast) only for host-to-controller messages.
 * @param can_id  out: the 11-bit identifier.
 * @param data  out: RP_MAX_PAYLOAD_BYTES bytes of room; data length = return value.
 * @return data length (0..8), or RP_ERR_BROADCAST, RP_ERR_NODE, RP_ERR_UNKNOWN_ID, the
 *         codes of rp_msg_pack (RP_ERR_FIELD(i), RP_ERR_LIMIT(i)), RP_ERR_NULL; checked
 *         in that order, as Python's encode_can does.
 */
int rp_can_encode(const rp_msg_t *msg, uint32_t node, bool strict, uint32_t *can_id,
                  uint8_t data[RP_MAX_PAYLOAD_BYTES]);

/** One decoded CAN frame. */
typedef struct {
    uint8_t node; /**< node id from the identifier */
    rp_msg_t msg; /**< the message */
} rp_can_frame_t;

/** CAN decoder: counters only (frames, unknown_id, bad_length, out_of_range, not_classic). */
typedef struct {
    rp_counters_t counters; /**< read freely; only ever grows */
} rp_can_decoder_t;

/** Zero the counters. */
void rp_can_decoder_init(rp_can_decoder_t *dec);

/**
 * Decode one received CAN frame.
 * @param can_id      arbitration identifier as received.
 * @param is_extended 29-bit frame (dropped: not_classic).
 * @param is_remote   remote frame (dropped: not_classic).
 * @param data        len bytes; may be NULL only if len is 0.
 * @return true and *frame filled for a valid frame; false (counted) otherwise.
 */
bool rp_can_decode(rp_can_decoder_t *dec, uint32_t can_id, bool is_extended, bool is_remote,
                   const uint8_t *data, size_t len, rp_can_frame_t *frame);

#ifdef __cplusplus
}
#endif

#endif /* ROVER_PROTO_H */
