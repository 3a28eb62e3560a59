/*
 * Fuzz target for the serial and CAN decoders (libFuzzer entry point).
 *
 *   clang -std=c99 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all \
 *       -I.. ../rover_msgs.c ../rover_proto.c fuzz_decoder.c -o fuzz_decoder
 *   ./fuzz_decoder -seed=1 -runs=1000000 new_corpus/ corpus_decoder/
 *
 * (make -C firmware_proto/wire/c fuzz-decoder; tests/firmware_proto/test_libfuzzer.py runs
 * it.) Without -fno-sanitize-recover=all UBSan only prints, and undefined behaviour
 * passes.
 *
 * Built with -DRP_FUZZ_MAIN (any C99 compiler, e.g. gcc with the sanitizers) it is a
 * plain program that runs the same checks over the files named on its command line.
 *
 * Input: byte 0 picks the chunk size (1..32), the rest is the serial stream. Checks,
 * beyond "no crash, no out-of-bounds access" (the sanitizers): every byte is consumed
 * and counted; every delivered frame has a known id and re-encodes (loose) to a frame
 * that decodes to the same field values; the CAN decoder, fed (identifier, data) pairs
 * cut from the same bytes, counts every frame exactly once.
 */
#include <stdlib.h>
#include <string.h>

#include "rover_proto.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void require(bool ok)
{
    if (!ok) {
        abort();
    }
}

static void same_fields(const rp_msg_t *a, const rp_msg_t *b)
{
    const rp_msg_info_t *info = rp_msg_info(a->id);
    require(info != NULL && a->id == b->id);
    for (unsigned k = 0; k < info->n_fields; ++k) {
        int64_t x = 0;
        int64_t y = 0;
        require(rp_msg_get_field(a, k, &x) == RP_OK && rp_msg_get_field(b, k, &y) == RP_OK);
        require(x == y);
    }
}

static void reencode(const rp_frame_t *frame)
{
    uint8_t wire[RP_MAX_WIRE_BYTES];
    const int n = rp_encode_message(&frame->msg, frame->seq, false, wire, sizeof wire);
    require(n > 0);
    rp_decoder_t dec;
    rp_decoder_init(&dec);
    rp_frame_t again;
    const uint8_t *p = wire;
    size_t left = (size_t)n;
    require(rp_decoder_feed(&dec, &p, &left, &again));
    require(again.seq == frame->seq);
    same_fields(&frame->msg, &again.msg);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size == 0u) {
        return 0;
    }
    const size_t step = 1u + data[0] % 32u;
    const uint8_t *stream = data + 1;
    size_t left = size - 1u;

    rp_decoder_t dec;
    rp_decoder_init(&dec);
    rp_frame_t frame;
    uint32_t delivered = 0;
    while (left > 0u) {
        const size_t n = left < step ? left : step;
        const uint8_t *p = stream;
        size_t m = n;
        while (rp_decoder_feed(&dec, &p, &m, &frame)) {
            require(rp_msg_info(frame.msg.id) != NULL);
            reencode(&frame);
            ++delivered;
        }
        require(m == 0u && p == stream + n);
        stream += n;
        left -= n;
    }
    require(dec.counters.bytes == (uint32_t)(size - 1u));
    require(dec.counters.frames == delivered);
    require(dec.counters.dropped_bytes <= dec.counters.bytes);

    rp_can_decoder_t can;
    rp_can_decoder_init(&can);
    rp_can_frame_t cframe;
    uint32_t seen = 0;
    for (size_t at = 1; at + 3u <= size; at += 3u + data[at + 2u] % 10u) {
        const uint32_t id = ((uint32_t)data[at] << 8 | data[at + 1u]) & 0xFFFu;
        size_t len = data[at + 2u] % 10u;
        if (len > size - at - 3u) {
            len = size - at - 3u;
        }
        const bool ext = (data[at] & 0x80u) != 0u;
        (void)rp_can_decode(&can, id, ext, false, data + at + 3u, len, &cframe);
        ++seen;
    }
    require(can.counters.frames + rp_counters_rejected(&can.counters) == seen);
    return 0;
}

#ifdef RP_FUZZ_MAIN
#include <stdio.h>

int main(int argc, char **argv)
{
    for (int i = 1; i < argc; ++i) {
        FILE *f = fopen(argv[i], "rb");
        if (f == NULL) {
            perror(argv[i]);
            return 2;
        }
        static uint8_t buf[1u << 20];
        const size_t n = fread(buf, 1u, sizeof buf, f);
        fclose(f);
        uint8_t *exact = malloc(n != 0u ? n : 1u);
        if (exact == NULL) {
            return 2;
        }
        memcpy(exact, buf, n);
        (void)LLVMFuzzerTestOneInput(exact, n);
        free(exact);
    }
    printf("ok %d inputs\n", argc - 1);
    return 0;
}
#endif
