/* vtexp-simavr: the reference firmware's very .elf on an emulated ATmega2560.
 *
 *   vtexp-simavr FIRMWARE.elf [--trace FILE] [--drop P] [--corrupt P] [--insert P]
 *                [--seed N] [--stack-from ADDR] [--peek ADDR:LEN]... [--profile FILE]
 *                [--fast | --lockstep FILE]
 *
 * It runs the firmware in simavr (Debian's libsimavr 1.6) at 16 MHz and
 *  - bridges USART0 to a pseudo-terminal of its own (firmware/pty/vt_pty.h, as the
 *    host build's), printed on stdout as "port /dev/pts/N" (simavr's own bridge wedges
 *    on writes of 512 bytes or more, and its fixed symlink collides when tests run side
 *    by side): host bytes are fed to the UART only while it signals room (XON), device
 *    bytes go to the pty;
 *  - paces simulated time to the wall clock (the firmware's clock is its 16 MHz
 *    crystal; the host's heartbeat and timeouts are wall time), unless --fast, and
 *    never faster: a lag of more than 2 ms (the process starved of the CPU) is lost,
 *    not caught up, as a crystal never runs fast ("lost_ns" at the end); with
 *    --lockstep FILE, the host keeps time by the chip instead: FILE holds two
 *    little-endian 64-bit counts of cycles, the chip's (written here after each step)
 *    and how far the host allows it to run (written by the host, vtexp's
 *    cfirmware.ChipClock, whenever it reads the chip's): the chip runs as fast as the
 *    computer goes, never further ahead of the host than that, and stands still while
 *    no host is looking;
 *  - times SPI transfers from SPCR/SPSR as the chip does (simavr 1.6 takes a fixed
 *    100 us per byte, which would stretch a 50-byte shift to 5 ms);
 *  - writes a trace, one JSON object per line with the CPU cycle "c": "latch" (rising
 *    edge of PB4, the chain's RCK or CS/LD, with the SPI bytes "d" shifted since the
 *    previous one), "oe" (PB5, with its pull-up: 1 = outputs disabled), "sync" (PB6),
 *    "port" (the SMA gate ports A, C, L and G bit 0), "rx0"/"tx0" (a frame delimiter
 *    into / out of the UART; "rx0" with "n", the bytes since the previous one: the
 *    frame's length), "reset", "wall" (wall-clock ns, every 100 ms), and at
 *    the end "tick_latency" (cycles from each Timer1 compare A to its handler: a
 *    histogram, the worst, and the program counter and interrupt that held it off),
 *    "stack" (deepest stack, bytes) and "peek" (memory asked for); "clock" when
 *    the firmware starts Timer1 (the cycle its device time 0 counts from);
 *  - injects line faults (each byte, both directions: dropped, altered, or followed by
 *    a random byte, with the given probabilities; seeded) and takes commands on stdin:
 *    "mute", "unmute" (no bytes either way), "unplug" (the pty closes), "replug" (a new
 *    pty, printed as "port ..."), "reset" (the reset pin), "faults D C I", "flush" (the
 *    trace, to read it while running), "quit";
 *  - with --profile, samples the program counter every 37 cycles and writes
 *    "BYTE_ADDRESS COUNT" lines at the end (4294967295 = asleep), for
 *    firmware/tools/profile.py to attribute to functions.
 * SIGTERM or SIGINT ends it cleanly (trace flushed). Exit status 0, or 1 on an error.
 */
#include <fcntl.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include <avr_ioport.h>
#include <avr_spi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_core.h>
#include <sim_elf.h>
#include <sim_io.h>
#include <sim_interrupts.h>
#include <sim_irq.h>
#include <sim_regbit.h>

#include "vt_pty.h"

#define MHZ 16000000ULL
#define RAM_START 0x200
#define RAM_END 0x21FF
#define PAINT 0xA5

static avr_t *avr;
static FILE *trace;
static uint8_t fast;
static vt_pty pty;

/* --lockstep: the chip's cycle count and how far the host lets it run (see the top) */
struct lockstep {
    volatile uint64_t cycle;
    volatile uint64_t allow;
};
static struct lockstep *step;

static int open_lockstep(const char *path)
{
    int fd = open(path, O_RDWR | O_CREAT, 0600);
    if (fd < 0 || ftruncate(fd, 4096) != 0) {
        perror(path);
        return -1;
    }
    step = mmap(NULL, 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    close(fd);
    if (step == MAP_FAILED) {
        perror(path);
        step = NULL;
        return -1;
    }
    step->cycle = 0;
    step->allow = 0;
    return 0;
}

/* ---------------------------------------------------------------- bytes in and out */

static int xoff;
static avr_irq_t *uart_in;
static uint8_t spi_buf[4096];
static uint16_t spi_n;
static int64_t max_lag_ns;
static uint64_t lost_ns;                   /* wall time the chip lost, starved */
/* How far behind the wall the chip may be and still catch up (at the computer's
 * speed): more is lost (see the main loop). */
#define LAG_KEPT_NS 2000000LL
static uint32_t *profile;                  /* samples per flash word address, --profile */
static avr_cycle_count_t next_sample;
/* Tick latency: cycles from Timer1 compare A raised to its handler entered (an edge
 * is late by as much), a histogram and the worst case with what held the tick off */
static avr_cycle_count_t lat_raised;
static uint32_t lat_pc, lat_worst_pc;
static uint8_t lat_running, lat_worst_vector;
static uint64_t lat_hist[128], lat_worst, lat_worst_at;
/* The tick handler's length, entry to return (nested interrupts included): the worst */
static avr_cycle_count_t tick_entered;
static uint64_t tick_len_worst, tick_len_worst_at;

static void trace_line(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void trace_line(const char *fmt, ...)
{
    if (!trace)
        return;
    va_list ap;
    va_start(ap, fmt);
    fprintf(trace, "{\"c\":%llu,", (unsigned long long)avr->cycle);
    vfprintf(trace, fmt, ap);
    fputs("}\n", trace);
    va_end(ap);
}

static void feed_uart(void)
{
    static unsigned since_zero;
    uint8_t b;
    while (!xoff && vt_pty_recv(&pty, &b)) {
        if (b == 0) {
            trace_line("\"e\":\"rx0\",\"n\":%u", since_zero);
            since_zero = 0;
        } else {
            since_zero++;
        }
        avr_raise_irq(uart_in, b);
    }
}

static void uart_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    (void)param;
    xoff = 0;
    feed_uart();
}

static void uart_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    (void)param;
    xoff = 1;
}

static void uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t b = (uint8_t)value;
    if (b == 0)
        trace_line("\"e\":\"tx0\"");
    vt_pty_send(&pty, b);
}

/* ---------------------------------------------------------------- pins and SPI */

static uint8_t pin_latch, pin_oe = 1, pin_sync;

static void pb_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    int bit = (int)(intptr_t)param;
    uint8_t v = value ? 1 : 0;
    if (bit == 4) {
        if (v && !pin_latch) {
            if (trace) {
                fprintf(trace, "{\"c\":%llu,\"e\":\"latch\",\"d\":\"", (unsigned long long)avr->cycle);
                for (uint16_t i = 0; i < spi_n; i++)
                    fprintf(trace, "%02x", spi_buf[i]);
                fputs("\"}\n", trace);
            }
            spi_n = 0;
        }
        pin_latch = v;
    } else if (bit == 5) {
        if (v != pin_oe)
            trace_line("\"e\":\"oe\",\"v\":%u", v);
        pin_oe = v;
    } else if (bit == 6) {
        if (v != pin_sync)
            trace_line("\"e\":\"sync\",\"v\":%u", v);
        pin_sync = v;
    }
}

static uint8_t port_val[4] = {0, 0, 0, 0};
static const char port_name[4] = {'A', 'C', 'L', 'G'};

static void gate_port(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    int i = (int)(intptr_t)param;
    uint8_t v = (uint8_t)(i == 3 ? (value & 1) : value);
    if (v != port_val[i])
        trace_line("\"e\":\"port\",\"p\":\"%c\",\"v\":%u", port_name[i], v);
    port_val[i] = v;
}

static void spi_byte(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (spi_n < sizeof spi_buf)
        spi_buf[spi_n++] = (uint8_t)value;
}

/* SPI timing as the chip has it: 8 bits at fosc / (4, 16, 64, 128), halved by SPI2X. */
static avr_spi_t *spi;

static avr_cycle_count_t spi_done(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)when;
    avr_spi_t *p = (avr_spi_t *)param;
    if (avr_regbit_get(a, p->spe) && avr_regbit_get(a, p->mstr)) {
        avr_raise_interrupt(a, &p->spi);
        avr_raise_irq(p->io.irq + SPI_IRQ_OUTPUT, a->data[p->r_spdr]);
    }
    return 0;
}

static void spi_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    static const uint8_t div[4] = {4, 16, 64, 128};
    avr_spi_t *p = (avr_spi_t *)param;
    avr_regbit_clear(a, p->spi.raised);
    avr_core_watch_write(a, addr, v);
    uint32_t d = div[a->data[p->r_spcr] & 3];
    if (avr_regbit_get(a, p->spr[2]))
        d >>= 1;
    avr_cycle_timer_register(a, 8 * d, spi_done, p);
}

/* Timer1's clock select being written: the firmware's clock starts (its time 0). */
static void tccr1b_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)a;
    (void)addr;
    (void)param;
    if (v & 7)
        trace_line("\"e\":\"clock\",\"tccr1b\":%u", v);
}

static void fix_spi_timing(void)
{
    for (avr_io_t *io = avr->io_port; io; io = io->next) {
        if (io->kind && !strcmp(io->kind, "spi")) {
            spi = (avr_spi_t *)io;
            avr_io_addr_t a = AVR_DATA_TO_IO(spi->r_spdr);
            avr->io[a].w.c = spi_write;
            avr->io[a].w.param = spi;
            return;
        }
    }
    fprintf(stderr, "vtexp-simavr: no SPI in this simavr core\n");
    exit(1);
}

/* ---------------------------------------------------------------- commands */

/* The harness's own, besides the pty's (vt_pty.h): "reset", the chip's reset pin. */
static int command(const char *line)
{
    if (!strcmp(line, "reset")) {
        avr_reset(avr);
        spi_n = 0;
        trace_line("\"e\":\"reset\"");
        if (!pin_oe)
            trace_line("\"e\":\"oe\",\"v\":1");
        pin_oe = 1;                           /* pins are inputs: the pull-up holds /G */
        for (int i = 0; i < 4; i++)
            if (port_val[i]) {
                port_val[i] = 0;              /* gate pull-downs */
                trace_line("\"e\":\"port\",\"p\":\"%c\",\"v\":0", port_name[i]);
            }
        return 1;
    }
    return 0;
}

/* ---------------------------------------------------------------- main */

static void tick_pending(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (!value)
        return;
    lat_raised = avr->cycle;
    lat_pc = avr->pc;
    lat_running = avr->interrupts.running_ptr
                      ? avr->interrupts.running[avr->interrupts.running_ptr - 1]->vector : 0;
}

static void tick_running(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (!value) {
        if (tick_entered && avr->cycle - tick_entered > tick_len_worst) {
            tick_len_worst = avr->cycle - tick_entered;
            tick_len_worst_at = tick_entered;
        }
        tick_entered = 0;
        return;
    }
    tick_entered = avr->cycle;
    if (!lat_raised)
        return;
    avr_cycle_count_t d = avr->cycle - lat_raised;
    lat_hist[d < 127 ? d : 127]++;
    if (d > lat_worst) {
        lat_worst = d;
        lat_worst_at = lat_raised;
        lat_worst_pc = lat_pc;                /* where the CPU was when the tick was due */
        lat_worst_vector = lat_running;       /* the interrupt it was in (0: none) */
    }
    lat_raised = 0;
}

static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a;
    (void)how_long;                           /* the main loop paces time itself */
}

int main(int argc, char **argv)
{
    const char *elf = NULL, *trace_path = NULL, *profile_path = NULL;
    unsigned long stack_from = 0;
    unsigned long peek_addr[16], peek_len[16];
    int n_peek = 0;
    vt_pty_init(&pty, "vtexp-simavr");
    pty.command = command;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--trace") && i + 1 < argc)
            trace_path = argv[++i];
        else if (vt_pty_option(&pty, argc, argv, &i))
            continue;
        else if (!strcmp(argv[i], "--stack-from") && i + 1 < argc)
            stack_from = strtoul(argv[++i], NULL, 0);
        else if (!strcmp(argv[i], "--peek") && i + 1 < argc && n_peek < 16) {
            char *colon;
            peek_addr[n_peek] = strtoul(argv[++i], &colon, 0);
            peek_len[n_peek] = *colon == ':' ? strtoul(colon + 1, NULL, 0) : 1;
            n_peek++;
        } else if (!strcmp(argv[i], "--profile") && i + 1 < argc) {
            profile_path = argv[++i];
            profile = calloc(0x20000, sizeof *profile);
        } else if (!strcmp(argv[i], "--fast"))
            fast = 1;
        else if (!strcmp(argv[i], "--lockstep") && i + 1 < argc) {
            if (open_lockstep(argv[++i]) != 0)
                return 1;
        }
        else if (argv[i][0] != '-' && !elf)
            elf = argv[i];
        else {
            fprintf(stderr, "vtexp-simavr: unknown argument %s\n", argv[i]);
            return 1;
        }
    }
    if (!elf) {
        fprintf(stderr, "usage: vtexp-simavr FIRMWARE.elf [--trace FILE] [--drop P] "
                        "[--corrupt P] [--insert P] [--seed N] [--fast | --lockstep FILE]\n");
        return 1;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "vtexp-simavr: cannot read %s\n", elf);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega2560");
    if (!avr || avr_init(avr) != 0) {
        fprintf(stderr, "vtexp-simavr: this simavr has no atmega2560\n");
        return 1;
    }
    avr->log = LOG_ERROR;
    avr->frequency = MHZ;
    avr_load_firmware(avr, &fw);
    avr->frequency = MHZ;
    avr->sleep = no_sleep;
    if (trace_path) {
        trace = fopen(trace_path, "w");
        if (!trace) {
            perror(trace_path);
            return 1;
        }
        setvbuf(trace, NULL, _IOFBF, 1 << 20);
        pty.trace = trace;
    }
    for (unsigned a = RAM_START; a <= RAM_END; a++)
        avr->data[a] = PAINT;                 /* to measure the deepest stack */

    fix_spi_timing();
    /* TIMER1_COMPA is vector 17 on the ATmega2560 */
    avr_irq_register_notify(avr_get_interrupt_irq(avr, 17) + AVR_INT_IRQ_PENDING, tick_pending,
                            NULL);
    avr_irq_register_notify(avr_get_interrupt_irq(avr, 17) + AVR_INT_IRQ_RUNNING, tick_running,
                            NULL);
    avr_register_io_write(avr, 0x81, tccr1b_write, NULL);    /* TCCR1B, shared with the timer */
    uint32_t f = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &f);
    f &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &f);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            uart_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            uart_xoff, NULL);
    for (int b = 4; b <= 6; b++)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), b), pb_pin,
                                (void *)(intptr_t)b);
    /* simavr 1.6 does not find the SPI's IRQs by ioctl; the module itself has them */
    avr_irq_register_notify(spi->io.irq + SPI_IRQ_OUTPUT, spi_byte, NULL);
    const char ports[3] = {'A', 'C', 'L'};
    for (int i = 0; i < 3; i++)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(ports[i]),
                                              IOPORT_IRQ_PIN_ALL),
                                gate_port, (void *)(intptr_t)i);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('G'), 0), gate_port,
                            (void *)(intptr_t)3);

    vt_pty_catch_signals();
    if (vt_pty_open(&pty) != 0)
        return 1;
    trace_line("\"e\":\"start\",\"hz\":%llu", (unsigned long long)MHZ);

    uint64_t t0 = vt_mono_ns(), next_wall = 0;
    while (!vt_pty_stopping) {
        uint64_t sim_ns = avr->cycle * 1000ULL / (MHZ / 1000000ULL);
        uint64_t wall_ns = vt_mono_ns() - t0;
        int64_t ahead = (fast || step) ? 0 : (int64_t)sim_ns - (int64_t)(wall_ns - lost_ns);
        uint64_t allow = step ? step->allow : UINT64_MAX;
        if (-ahead > max_lag_ns && !step)
            max_lag_ns = -ahead;
        if (-ahead > LAG_KEPT_NS && !step) {
            /* Starved of the CPU, the chip fell behind: the time is lost, not caught up
               by running faster than the wall. A chip's crystal never runs fast; catching
               up would stretch every wall-timed interval of the host's (a heartbeat, a
               train the host cuts at its maximum on-time) on the chip's clock. */
            lost_ns += (uint64_t)(-ahead - LAG_KEPT_NS);
            ahead = -LAG_KEPT_NS;
        }
        if (ahead <= 50000 && avr->cycle < allow) {
            /* run at most 100 us of simulated time (in lockstep: no further than the host
               allows), then look at the wall and the pty */
            avr_cycle_count_t until = avr->cycle + MHZ / 10000;
            if (until > allow)
                until = allow;
            while (avr->cycle < until && avr->state != cpu_Done && avr->state != cpu_Crashed) {
                avr_flashaddr_t pc = avr->pc;
                int was = avr->state;
                avr->run(avr);
                /* the cycles just spent belong to that instruction, or to sleep */
                while (profile && next_sample < avr->cycle) {
                    profile[was == cpu_Sleeping ? 0x1FFFF : (pc >> 1) & 0x1FFFF]++;
                    next_sample += 37;
                }
            }
            if (avr->state == cpu_Done || avr->state == cpu_Crashed) {
                fprintf(stderr, "vtexp-simavr: the firmware stopped (state %d)\n", avr->state);
                break;
            }
            ahead = 0;
            if (step)
                step->cycle = avr->cycle;
        }
        if (sim_ns >= next_wall) {
            trace_line("\"e\":\"wall\",\"ns\":%llu", (unsigned long long)wall_ns);
            if (trace)
                fflush(trace);
            next_wall = sim_ns + 100000000ULL;
        }
        uint64_t wait_ns = 0;
        if (!fast && ahead > 50000)             /* more than 50 us ahead: let the wall catch up */
            wait_ns = ahead > 20000000 ? 20000000 : (uint64_t)ahead;
        else if (step && avr->cycle >= step->allow)
            wait_ns = 200000;                   /* lockstep: until the host looks again */
        vt_pty_wait(&pty, wait_ns);
        vt_pty_flush(&pty);
        feed_uart();
    }
    unsigned long deepest = 0;
    if (stack_from) {
        unsigned long a = stack_from;
        while (a <= RAM_END && avr->data[a] == PAINT)
            a++;
        deepest = RAM_END + 1 - a;
        trace_line("\"e\":\"stack\",\"from\":%lu,\"used\":%lu", stack_from, deepest);
    }
    for (int i = 0; i < n_peek; i++) {
        if (!trace)
            break;
        fprintf(trace, "{\"c\":%llu,\"e\":\"peek\",\"a\":%lu,\"d\":\"", (unsigned long long)avr->cycle,
                peek_addr[i]);
        for (unsigned long k = 0; k < peek_len[i] && peek_addr[i] + k <= RAM_END; k++)
            fprintf(trace, "%02x", avr->data[peek_addr[i] + k]);
        fputs("\"}\n", trace);
    }
    if (trace) {
        fprintf(trace, "{\"c\":%llu,\"e\":\"tick_latency\",\"worst\":%llu,\"worst_at\":%llu,"
                       "\"worst_pc\":%u,\"worst_vector\":%u,\"handler_worst\":%llu,"
                       "\"handler_worst_at\":%llu,\"hist\":{",
                (unsigned long long)avr->cycle, (unsigned long long)lat_worst,
                (unsigned long long)lat_worst_at, (unsigned)lat_worst_pc, lat_worst_vector,
                (unsigned long long)tick_len_worst, (unsigned long long)tick_len_worst_at);
        const char *sep = "";
        for (int d = 0; d < 128; d++)
            if (lat_hist[d]) {
                fprintf(trace, "%s\"%d\":%llu", sep, d, (unsigned long long)lat_hist[d]);
                sep = ",";
            }
        fputs("}}\n", trace);
    }
    trace_line("\"e\":\"end\",\"rx\":%llu,\"tx\":%llu,\"dropped\":%llu,\"corrupted\":%llu,"
               "\"inserted\":%llu,\"max_lag_ns\":%lld,\"lost_ns\":%llu",
               (unsigned long long)pty.n_rx, (unsigned long long)pty.n_tx,
               (unsigned long long)pty.n_dropped, (unsigned long long)pty.n_corrupted,
               (unsigned long long)pty.n_inserted, (long long)max_lag_ns,
               (unsigned long long)lost_ns);
    if (trace)
        fclose(trace);
    if (profile) {
        FILE *pf = fopen(profile_path, "w");
        for (uint32_t a = 0; pf && a < 0x20000; a++)
            if (profile[a])
                fprintf(pf, "%u %u\n", a == 0x1FFFF ? 0xFFFFFFFFu : 2 * a, profile[a]);
        if (pf)
            fclose(pf);
    }
    vt_pty_close(&pty);
    fprintf(stderr, "vtexp-simavr: stopped after %.3f s simulated (max lag behind the wall "
                    "clock %.1f ms, %.1f ms lost)\n", (double)avr->cycle / MHZ,
            (double)max_lag_ns / 1e6, (double)lost_ns / 1e6);
    return 0;
}
