/* COBS, one byte at a time (see vt_cobs.h). */
#include "vt_cobs.h"
#include "vt_hal.h"

static uint8_t block[254];
static uint8_t n, full;

static void flush(uint8_t code)
{
    vt_hal_tx(code);
    for (uint8_t i = 0; i < n; i++)
        vt_hal_tx(block[i]);
    n = 0;
}

void vt_cobs_enc_begin(void)
{
    n = 0;
    full = 0;
}

void vt_cobs_enc_byte(uint8_t b)
{
    full = 0;
    if (b == 0) {
        flush((uint8_t)(n + 1));
        return;
    }
    block[n++] = b;
    if (n == 254) {                       /* a full block: no zero follows it */
        flush(0xFF);
        full = 1;
    }
}

void vt_cobs_enc_end(void)
{
    if (!full)
        flush((uint8_t)(n + 1));
}

void vt_cobs_dec_init(vt_cobs_dec *d, uint8_t *buf, uint16_t cap)
{
    d->buf = buf;
    d->cap = cap;
    d->len = 0;
    d->code = d->left = d->started = d->over = 0;
}

int16_t vt_cobs_dec_end(vt_cobs_dec *d)
{
    int16_t r = (int16_t)d->len;
    if (!d->started && !d->over)
        r = VT_COBS_EMPTY;
    else if (d->over)
        r = VT_COBS_TOO_LONG;
    else if (d->left != 0)
        r = VT_COBS_BAD;
    d->len = 0;
    d->code = d->left = d->started = d->over = 0;
    return r;
}
