/* COBS (Consistent Overhead Byte Stuffing, Cheshire & Baker 1999), both directions,
 * one byte at a time, so that neither end needs a second buffer for a frame.
 *
 * The encoder holds at most one block (254 bytes) and sends through vt_hal_tx();
 * a block of 254 non-zero bytes at the very end takes no closing code (the form of
 * the Wikipedia article, which docs/protocol.md and the Python codec use). The
 * decoder writes the decoded bytes into the caller's buffer as they arrive and
 * stops storing (but keeps count of the overflow) past its capacity.
 */
#ifndef VT_COBS_H
#define VT_COBS_H

#include <stdint.h>

void vt_cobs_enc_begin(void);
void vt_cobs_enc_byte(uint8_t b);
void vt_cobs_enc_end(void);

typedef struct {
    uint8_t *buf;
    uint16_t len, cap;
    uint8_t code, left, started, over;
} vt_cobs_dec;

enum { VT_COBS_EMPTY = -1, VT_COBS_BAD = -2, VT_COBS_TOO_LONG = -3 };

void vt_cobs_dec_init(vt_cobs_dec *d, uint8_t *buf, uint16_t cap);

/* A byte of an encoded frame (never the zero delimiter). Inline: it runs for every byte
 * received, 100,000 times a second at 1 Mbaud. */
static inline void vt_cobs_dec_byte(vt_cobs_dec *d, uint8_t b)
{
    if (d->over)
        return;                           /* too long already: dropped up to the delimiter */
    if (d->left == 0) {                   /* a code byte: the zero it stands for comes first */
        if (d->started && d->code != 0xFF) {
            if (d->len >= d->cap) {
                d->over = 1;
                return;
            }
            d->buf[d->len++] = 0;
        }
        d->code = b;
        d->left = (uint8_t)(b - 1);
        d->started = 1;
        return;
    }
    if (d->len >= d->cap) {
        d->over = 1;
        return;
    }
    d->buf[d->len++] = b;
    d->left--;
}
/* The delimiter: the decoded length, or VT_COBS_EMPTY (nothing since the last one),
 * VT_COBS_BAD (a block runs past the end), VT_COBS_TOO_LONG (more than cap bytes).
 * The decoder is ready for the next frame. */
int16_t vt_cobs_dec_end(vt_cobs_dec *d);

#endif
