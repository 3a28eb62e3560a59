/*
 * rp_tool: a line-oriented test harness around the C reference codec, driven by the
 * Python tests (tests/firmware_proto/test_c_codec.py) through pipes. Not part of the
 * library: it uses stdio and the heap. Every input line is independent; every output
 * line starts with a keyword. Usage: rp_tool MODE [ARGS] < input > output
 *
 *   decode              each line: hex bytes, fed to one decoder as one chunk
 *                       out: "frame ID SEQ f=v ..." per frame, then "counters k=v ..."
 *   encode              each line: "NAME SEQ [strict=0] f=v ..."
 *                       out: "ok HEX" (wire bytes, delimiters included) or
 *                            "error RC range|limit|other FIELD|-"
 *   can-encode          each line: "NAME NODE [strict=0] f=v ..."
 *                       out: "ok CANID_HEX DATA_HEX" or "error ..." as for encode
 *   can-decode          each line: "CANID_HEX EXT RTR DATA_HEX|-"
 *                       out: "frame NODE ID f=v ..." or "drop", then "counters ..."
 *   cobs-encode|cobs-decode|crc
 *                       each line: hex; out: "ok HEX" or "error RC"
 *   fuzz SEED MAXCHUNK  stdin: raw bytes, fed in chunks of 1..MAXCHUNK bytes picked by
 *                       xorshift32(SEED), each chunk copied to its own heap block so the
 *                       sanitizers see any read past it; out: frames and counters as decode
 *   selftest            API contracts Python cannot reach (NULLs, capacities, in place)
 *
 * Exit status: 0 done, 1 a selftest check failed, 2 usage or malformed input line.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rover_proto.h"

static void die(const char *what, const char *line)
{
    fprintf(stderr, "rp_tool: %s: %s\n", what, line != NULL ? line : "");
    exit(2);
}

/* One line of stdin without its newline, in a growing heap buffer; NULL at EOF. */
static char *read_line(char **buf, size_t *cap)
{
    size_t n = 0;
    int ch;
    while ((ch = getchar()) != EOF && ch != '\n') {
        if (n + 1u >= *cap) {
            size_t grown = *cap != 0u ? *cap * 2u : 256u;
            char *p = realloc(*buf, grown);
            if (p == NULL) {
                die("out of memory", NULL);
            }
            *buf = p;
            *cap = grown;
        }
        (*buf)[n++] = (char)ch;
    }
    if (ch == EOF && n == 0u) {
        return NULL;
    }
    if (*buf == NULL) {
        *buf = malloc(1u);
        *cap = 1u;
        if (*buf == NULL) {
            die("out of memory", NULL);
        }
    }
    (*buf)[n] = '\0';
    return *buf;
}

static int hex_digit(char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1;
}

/* Hex text (spaces ignored) into a fresh heap block of exactly the decoded size. */
static uint8_t *parse_hex(const char *text, size_t *len)
{
    size_t digits = 0;
    for (const char *p = text; *p != '\0'; ++p) {
        if (*p == ' ') {
            continue;
        }
        if (hex_digit(*p) < 0) {
            die("not hex", text);
        }
        ++digits;
    }
    if (digits % 2u != 0u) {
        die("odd number of hex digits", text);
    }
    *len = digits / 2u;
    uint8_t *out = malloc(*len != 0u ? *len : 1u);
    if (out == NULL) {
        die("out of memory", NULL);
    }
    size_t k = 0;
    int high = -1;
    for (const char *p = text; *p != '\0'; ++p) {
        if (*p == ' ') {
            continue;
        }
        if (high < 0) {
            high = hex_digit(*p);
        } else {
            out[k++] = (uint8_t)((high << 4) | hex_digit(*p));
            high = -1;
        }
    }
    return out;
}

static void print_hex(const uint8_t *data, size_t len)
{
    for (size_t k = 0; k < len; ++k) {
        printf("%02x", data[k]);
    }
}

static void print_fields(const rp_msg_t *msg)
{
    const rp_msg_info_t *info = rp_msg_info(msg->id);
    for (unsigned k = 0; info != NULL && k < info->n_fields; ++k) {
        int64_t value = 0;
        if (rp_msg_get_field(msg, k, &value) != RP_OK) {
            die("get_field failed", info->name);
        }
        printf(" %s=%lld", info->fields[k].name, (long long)value);
    }
}

static void print_counters(const rp_counters_t *c)
{
    printf("counters frames=%lu bytes=%lu dropped_bytes=%lu framing=%lu oversize=%lu crc=%lu "
           "unknown_id=%lu bad_length=%lu out_of_range=%lu lost=%lu not_classic=%lu\n",
           (unsigned long)c->frames, (unsigned long)c->bytes, (unsigned long)c->dropped_bytes,
           (unsigned long)c->framing, (unsigned long)c->oversize, (unsigned long)c->crc,
           (unsigned long)c->unknown_id, (unsigned long)c->bad_length,
           (unsigned long)c->out_of_range, (unsigned long)c->lost,
           (unsigned long)c->not_classic);
}

static void print_frame(const rp_frame_t *f)
{
    printf("frame %u %u", (unsigned)f->msg.id, (unsigned)f->seq);
    print_fields(&f->msg);
    printf("\n");
}

static void feed_chunk(rp_decoder_t *dec, const uint8_t *chunk, size_t len)
{
    rp_frame_t frame;
    if (len == 1u) {
        if (rp_decoder_put(dec, chunk[0], &frame)) {
            print_frame(&frame);
        }
        return;
    }
    const uint8_t *p = chunk;
    size_t n = len;
    while (rp_decoder_feed(dec, &p, &n, &frame)) {
        print_frame(&frame);
    }
    if (n != 0u) {
        die("decoder left bytes unconsumed", NULL);
    }
}

static int mode_decode(void)
{
    rp_decoder_t dec;
    rp_decoder_init(&dec);
    char *buf = NULL;
    size_t cap = 0;
    const char *line;
    while ((line = read_line(&buf, &cap)) != NULL) {
        size_t len = 0;
        uint8_t *chunk = parse_hex(line, &len);
        feed_chunk(&dec, chunk, len);
        free(chunk);
    }
    free(buf);
    print_counters(&dec.counters);
    return 0;
}

/* xorshift32 (Marsaglia 2003); the Python test replicates it to chunk identically. */
static uint32_t xorshift32(uint32_t *state)
{
    uint32_t x = *state;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    *state = x;
    return x;
}

static int mode_fuzz(const char *seed_text, const char *max_text)
{
    uint32_t state = (uint32_t)strtoul(seed_text, NULL, 0);
    const unsigned long max_chunk = strtoul(max_text, NULL, 0);
    if (state == 0u || max_chunk == 0u) {
        die("fuzz needs a non-zero SEED and MAXCHUNK", NULL);
    }
    size_t cap = 1u << 16;
    size_t len = 0;
    uint8_t *data = malloc(cap);
    if (data == NULL) {
        die("out of memory", NULL);
    }
    size_t got;
    while ((got = fread(data + len, 1u, cap - len, stdin)) > 0u) {
        len += got;
        if (len == cap) {
            cap *= 2u;
            uint8_t *p = realloc(data, cap);
            if (p == NULL) {
                die("out of memory", NULL);
            }
            data = p;
        }
    }
    rp_decoder_t dec;
    rp_decoder_init(&dec);
    size_t at = 0;
    while (at < len) {
        size_t n = (size_t)(1u + xorshift32(&state) % max_chunk);
        if (n > len - at) {
            n = len - at;
        }
        uint8_t *chunk = malloc(n);
        if (chunk == NULL) {
            die("out of memory", NULL);
        }
        memcpy(chunk, data + at, n);
        feed_chunk(&dec, chunk, n);
        free(chunk);
        at += n;
    }
    free(data);
    print_counters(&dec.counters);
    return 0;
}

/* Parse "f=v ..." tokens (after the two leading ones) into msg; returns the strict flag. */
static bool parse_fields(char *rest, rp_msg_t *msg, const rp_msg_info_t *info, int *rc,
                         unsigned *bad_field)
{
    bool strict = true;
    *rc = RP_OK;
    for (char *tok = strtok(rest, " "); tok != NULL; tok = strtok(NULL, " ")) {
        char *eq = strchr(tok, '=');
        if (eq == NULL) {
            die("expected FIELD=VALUE", tok);
        }
        *eq = '\0';
        char *end = NULL;
        const long long value = strtoll(eq + 1, &end, 0);
        if (end == eq + 1 || *end != '\0') {
            die("not an integer", eq + 1);
        }
        if (strcmp(tok, "strict") == 0) {
            strict = value != 0;
            continue;
        }
        unsigned k = 0;
        while (k < info->n_fields && strcmp(info->fields[k].name, tok) != 0) {
            ++k;
        }
        if (k == info->n_fields) {
            die("unknown field", tok);
        }
        const int set = rp_msg_set_field(msg, k, (int64_t)value);
        if (set != RP_OK && (*rc == RP_OK || k < *bad_field)) {
            /* Not representable in the struct member: remember the lowest such index. */
            *rc = set;
            *bad_field = k;
        }
    }
    return strict;
}

static void print_error(int rc, const rp_msg_info_t *info)
{
    const int k = rp_err_field_index(rc);
    const char *kind = k < 0 ? "other" : rp_err_is_limit(rc) ? "limit" : "range";
    const char *name = (k >= 0 && info != NULL && (unsigned)k < info->n_fields)
                           ? info->fields[k].name
                           : "-";
    printf("error %d %s %s\n", rc, kind, name);
}

static int mode_encode(bool can)
{
    char *buf = NULL;
    size_t cap = 0;
    char *line;
    while ((line = read_line(&buf, &cap)) != NULL) {
        char *name = strtok(line, " ");
        char *number = strtok(NULL, " ");
        char *rest = strtok(NULL, "");
        if (name == NULL || number == NULL) {
            die("expected NAME NUMBER [FIELD=VALUE ...]", line);
        }
        const rp_msg_info_t *info = rp_msg_by_name(name);
        if (info == NULL) {
            die("unknown message", name);
        }
        const unsigned long seq_or_node = strtoul(number, NULL, 0);
        rp_msg_t msg;
        memset(&msg, 0, sizeof msg);
        msg.id = info->id;
        int rc;
        unsigned bad = 0;
        char empty[] = "";
        int unrepresentable = RP_OK;
        const bool strict =
            parse_fields(rest != NULL ? rest : empty, &msg, info, &unrepresentable, &bad);
        uint32_t id = 0;
        uint8_t out[RP_MAX_WIRE_BYTES];
        if (can) {
            rc = rp_can_encode(&msg, (uint32_t)seq_or_node, strict, &id, out);
        } else {
            rc = rp_encode_message(&msg, (uint8_t)(seq_or_node & 0xFFu), strict, out, sizeof out);
        }
        if (unrepresentable != RP_OK) {
            /* A value the struct cannot hold is out of its wire range too; it was left 0.
             * Python reports the node first, then the lowest-index wire-range error. */
            const int k = rp_err_field_index(rc);
            const bool earlier = k >= 0 && !rp_err_is_limit(rc) && (unsigned)k < bad;
            if (rc >= 0 || rp_err_is_limit(rc) || (k >= 0 && !earlier)) {
                rc = RP_ERR_FIELD(bad);
            }
        }
        if (rc < 0) {
            print_error(rc, info);
            continue;
        }
        if (can) {
            printf("ok %03lx ", (unsigned long)id);
        } else {
            printf("ok ");
        }
        print_hex(out, (size_t)rc);
        printf("\n");
    }
    free(buf);
    return 0;
}

static int mode_can_decode(void)
{
    rp_can_decoder_t dec;
    rp_can_decoder_init(&dec);
    char *buf = NULL;
    size_t cap = 0;
    char *line;
    while ((line = read_line(&buf, &cap)) != NULL) {
        char *id_text = strtok(line, " ");
        char *ext = strtok(NULL, " ");
        char *rtr = strtok(NULL, " ");
        char *hex = strtok(NULL, " ");
        if (id_text == NULL || ext == NULL || rtr == NULL || hex == NULL) {
            die("expected CANID EXT RTR DATA", line);
        }
        size_t len = 0;
        uint8_t *data = parse_hex(strcmp(hex, "-") == 0 ? "" : hex, &len);
        rp_can_frame_t frame;
        const uint32_t can_id = (uint32_t)strtoul(id_text, NULL, 16);
        if (rp_can_decode(&dec, can_id, strcmp(ext, "1") == 0, strcmp(rtr, "1") == 0, data, len,
                          &frame)) {
            printf("frame %u %u", (unsigned)frame.node, (unsigned)frame.msg.id);
            print_fields(&frame.msg);
            printf("\n");
        } else {
            printf("drop\n");
        }
        free(data);
    }
    free(buf);
    print_counters(&dec.counters);
    return 0;
}

static int mode_bytes(const char *mode)
{
    char *buf = NULL;
    size_t cap = 0;
    const char *line;
    while ((line = read_line(&buf, &cap)) != NULL) {
        size_t len = 0;
        uint8_t *in = parse_hex(line, &len);
        if (strcmp(mode, "crc") == 0) {
            printf("ok %04x\n", (unsigned)rp_crc16(in, len));
            free(in);
            continue;
        }
        const size_t room = strcmp(mode, "cobs-encode") == 0 ? len + len / 254u + 1u : len;
        uint8_t *out = malloc(room != 0u ? room : 1u);
        if (out == NULL) {
            die("out of memory", NULL);
        }
        const int rc = strcmp(mode, "cobs-encode") == 0 ? rp_cobs_encode(in, len, out, room)
                                                        : rp_cobs_decode(in, len, out, room);
        if (rc < 0) {
            printf("error %d\n", rc);
        } else {
            printf("ok ");
            print_hex(out, (size_t)rc);
            printf("\n");
        }
        free(out);
        free(in);
    }
    free(buf);
    return 0;
}

static int failures;

static void check(bool ok, const char *what)
{
    if (!ok) {
        printf("FAIL %s\n", what);
        ++failures;
    }
}

static int mode_selftest(void)
{
    static const uint8_t check_string[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    check(rp_crc16(check_string, sizeof check_string) == 0x29B1u, "crc check value");
    check(rp_crc16(NULL, 0u) == 0xFFFFu, "crc of nothing");

    uint8_t out[RP_MAX_WIRE_BYTES];
    rp_msg_t msg;
    memset(&msg, 0, sizeof msg);
    msg.id = RP_MSG_MOTION;
    msg.body.motion.seq = 1u;
    msg.body.motion.command = RP_COMMAND_FWD;
    msg.body.motion.speed = 30u;
    msg.body.motion.distance = 23000u;
    const int n = rp_encode_message(&msg, 7u, true, out, sizeof out);
    check(n > 0 && (size_t)n <= RP_MAX_WIRE_BYTES, "encode MOTION");
    for (size_t cap = 0; n > 0 && cap < (size_t)n; ++cap) {
        check(rp_encode_message(&msg, 7u, true, out, cap) == RP_ERR_BUFFER, "small buffer");
    }
    check(rp_encode_message(NULL, 0u, true, out, sizeof out) == RP_ERR_NULL, "NULL msg");
    check(rp_encode_frame(1u, 0u, out, RP_MAX_PAYLOAD_BYTES + 1u, out, sizeof out) ==
              RP_ERR_LENGTH,
          "payload too long");
    msg.body.motion.speed = 61u;
    check(rp_msg_pack(&msg, true, out, sizeof out) == RP_ERR_LIMIT(RP_F_MOTION_SPEED),
          "strict limit names speed");
    check(rp_msg_pack(&msg, false, out, sizeof out) == (int)RP_MSG_MOTION_LEN, "loose pack");
    check(rp_motion_pack(&msg.body.motion, true, out, RP_MSG_MOTION_LEN - 1u) == RP_ERR_BUFFER,
          "pack capacity");
    check(rp_motion_unpack(&msg.body.motion, out, RP_MSG_MOTION_LEN + 1u) == RP_ERR_LENGTH,
          "unpack length");
    check(rp_err_field_index(RP_ERR_LIMIT(3)) == 3 && rp_err_is_limit(RP_ERR_LIMIT(3)),
          "limit code");
    check(rp_err_field_index(RP_ERR_FIELD(2)) == 2 && !rp_err_is_limit(RP_ERR_FIELD(2)),
          "field code");
    check(rp_err_field_index(RP_ERR_BUFFER) == -1, "not a field code");
    check(rp_msg_info(128u) == NULL && rp_msg_info(5u) == NULL, "unknown ids");
    check(rp_msg_by_name("MOTIO") == NULL && rp_msg_by_name("MOTIONS") == NULL, "by name");
    check(rp_msg_by_name("MOTION") == rp_msg_info(RP_MSG_MOTION), "by name MOTION");
    for (unsigned k = 1; k < RP_MSG_COUNT; ++k) {
        check(rp_msg_table[k - 1u].id < rp_msg_table[k].id, "table sorted by id");
    }

    /* COBS: in-place decoding, and every capacity short of the need is refused. */
    uint8_t block[] = {0x03, 0x11, 0x22, 0x02, 0x33, 0x01};
    const int d = rp_cobs_decode(block, sizeof block, block, sizeof block);
    check(d == 5 && block[0] == 0x11 && block[1] == 0x22 && block[2] == 0 && block[3] == 0x33 &&
              block[4] == 0,
          "cobs decode in place");
    uint8_t plain[300];
    for (size_t k = 0; k < sizeof plain; ++k) {
        plain[k] = (uint8_t)(k % 7u == 3u ? 0u : k + 1u);
    }
    uint8_t enc[RP_COBS_MAX_ENCODED(300u)];
    const int e = rp_cobs_encode(plain, sizeof plain, enc, sizeof enc);
    check(e > 0, "cobs encode");
    for (size_t cap = 0; e > 0 && cap < (size_t)e; ++cap) {
        check(rp_cobs_encode(plain, sizeof plain, enc, cap) == RP_ERR_BUFFER, "cobs capacity");
    }
    check(rp_cobs_decode(NULL, 1u, enc, sizeof enc) == RP_ERR_NULL, "cobs NULL");

    /* Decoder: NULL arguments are refused without touching anything. */
    rp_decoder_t dec;
    rp_decoder_init(&dec);
    rp_frame_t frame;
    const uint8_t *p = NULL;
    size_t len = 3u;
    check(!rp_decoder_feed(&dec, &p, &len, &frame) && len == 3u, "feed NULL data");
    check(!rp_decoder_feed(NULL, &p, &len, &frame), "feed NULL decoder");
    len = 0u;
    check(!rp_decoder_feed(&dec, &p, &len, &frame), "feed nothing");
    check(dec.counters.bytes == 0u, "nothing counted");

    /* CAN: node and broadcast checks, in Python's order. */
    uint32_t can_id = 0;
    uint8_t data[RP_MAX_PAYLOAD_BYTES];
    msg.body.motion.speed = 30u;
    check(rp_can_encode(&msg, 16u, true, &can_id, data) == RP_ERR_NODE, "node 16");
    check(rp_can_encode(&msg, 0u, true, &can_id, data) == (int)RP_MSG_MOTION_LEN, "broadcast");
    check(can_id == 0x080u, "MOTION broadcast id");
    msg.id = RP_MSG_ACK;
    check(rp_can_encode(&msg, 0u, true, &can_id, data) == RP_ERR_BROADCAST, "ACK broadcast");
    check(rp_can_id(128u, 1u) == RP_ERR_UNKNOWN_ID && rp_can_id(0u, 0u) == 0, "can id range");
    rp_can_decoder_t cdec;
    rp_can_decoder_init(&cdec);
    rp_can_frame_t cframe;
    check(!rp_can_decode(&cdec, 0x081u, false, false, NULL, 6u, &cframe), "can NULL data");
    check(cdec.counters.bad_length == 0u, "NULL not counted");

    if (failures == 0) {
        printf("ok selftest\n");
    }
    return failures == 0 ? 0 : 1;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        die("usage", "rp_tool decode|encode|can-encode|can-decode|cobs-encode|cobs-decode|"
                     "crc|fuzz SEED MAXCHUNK|selftest");
    }
    const char *mode = argv[1];
    int rc;
    if (strcmp(mode, "decode") == 0) {
        rc = mode_decode();
    } else if (strcmp(mode, "encode") == 0) {
        rc = mode_encode(false);
    } else if (strcmp(mode, "can-encode") == 0) {
        rc = mode_encode(true);
    } else if (strcmp(mode, "can-decode") == 0) {
        rc = mode_can_decode();
    } else if (strcmp(mode, "cobs-encode") == 0 || strcmp(mode, "cobs-decode") == 0 ||
               strcmp(mode, "crc") == 0) {
        rc = mode_bytes(mode);
    } else if (strcmp(mode, "fuzz") == 0 && argc == 4) {
        rc = mode_fuzz(argv[2], argv[3]);
    } else if (strcmp(mode, "selftest") == 0) {
        rc = mode_selftest();
    } else {
        die("unknown mode", mode);
    }
    if (fflush(stdout) != 0) {
        return 2;
    }
    return rc;
}
