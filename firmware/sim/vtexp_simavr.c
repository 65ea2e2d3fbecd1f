/* vtexp-simavr: the reference firmware's very .elf on an emulated ATmega2560.
 *
 *   vtexp-simavr FIRMWARE.elf [--trace FILE] [--drop P] [--corrupt P] [--insert P]
 *                [--seed N] [--stack-from ADDR] [--peek ADDR:LEN]... [--profile FILE]
 *                [--fast]
 *
 * It runs the firmware in simavr (Debian's libsimavr 1.6) at 16 MHz and
 *  - bridges USART0 to a pseudo-terminal of its own, printed on stdout as
 *    "port /dev/pts/N" (simavr's own bridge wedges on writes of 512 bytes or more,
 *    and its fixed symlink collides when tests run side by side): host bytes are fed
 *    to the UART only while it signals room (XON), device bytes go to the pty;
 *  - paces simulated time to the wall clock (the firmware's clock is its 16 MHz
 *    crystal; the host's heartbeat and timeouts are wall time), unless --fast;
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
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
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

#define MHZ 16000000ULL
#define RAM_START 0x200
#define RAM_END 0x21FF
#define PAINT 0xA5

static avr_t *avr;
static FILE *trace;
static volatile sig_atomic_t stopping;
static int master = -1, slave = -1, muted, unplugged;
static double p_drop, p_corrupt, p_insert;
static uint64_t rng = 0x9E3779B97F4A7C15ULL;
static uint8_t fast;

/* ---------------------------------------------------------------- bytes in and out */

static uint8_t in_q[1 << 16];
static uint32_t in_head, in_tail;          /* host -> device, waiting for the UART */
static uint8_t out_q[1 << 16];
static uint32_t out_head, out_tail;        /* device -> host, waiting for the pty */
static int xoff;
static avr_irq_t *uart_in;
static uint8_t spi_buf[4096];
static uint16_t spi_n;
static uint64_t stats_rx, stats_tx, stats_dropped, stats_corrupted, stats_inserted;
static int64_t max_lag_ns;
static uint32_t *profile;                  /* samples per flash word address, --profile */
static avr_cycle_count_t next_sample;
/* Tick latency: cycles from Timer1 compare A raised to its handler entered (an edge
 * is late by as much), a histogram and the worst case with what held the tick off */
static avr_cycle_count_t lat_raised;
static uint32_t lat_pc, lat_worst_pc;
static uint8_t lat_running, lat_worst_vector;
static uint64_t lat_hist[128], lat_worst, lat_worst_at;

static double uniform(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (double)(rng >> 11) / (double)(1ULL << 53);
}

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

/* A byte on the line, with faults: returns how many bytes (0-2) to pass on in out[]. */
static int mangle(uint8_t b, uint8_t out[2])
{
    if (p_drop > 0 && uniform() < p_drop) {
        stats_dropped++;
        return 0;
    }
    if (p_corrupt > 0 && uniform() < p_corrupt) {
        b ^= (uint8_t)(1 + (uint8_t)(uniform() * 255));
        stats_corrupted++;
    }
    out[0] = b;
    if (p_insert > 0 && uniform() < p_insert) {
        out[1] = (uint8_t)(uniform() * 256);
        stats_inserted++;
        return 2;
    }
    return 1;
}

static void feed_uart(void)
{
    static unsigned since_zero;
    while (!xoff && in_tail != in_head) {
        uint8_t b = in_q[in_tail++ & 0xFFFF];
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
    uint8_t b = (uint8_t)value, m[2];
    stats_tx++;
    if (b == 0)
        trace_line("\"e\":\"tx0\"");
    if (muted || unplugged || master < 0)
        return;                               /* the UART sends into nothing */
    int n = mangle(b, m);
    for (int i = 0; i < n; i++)
        out_q[out_head++ & 0xFFFF] = m[i];
}

static void pump_out(void)
{
    while (out_tail != out_head && master >= 0) {
        uint32_t n = out_head - out_tail;
        uint32_t at = out_tail & 0xFFFF;
        if (at + n > sizeof out_q)
            n = (uint32_t)sizeof out_q - at;
        ssize_t w = write(master, &out_q[at], n);
        if (w <= 0)
            return;                           /* the host is not reading: keep it for later */
        out_tail += (uint32_t)w;
    }
}

static void read_host(void)
{
    uint8_t buf[4096];
    ssize_t n = read(master, buf, sizeof buf);
    if (n <= 0)
        return;
    if (muted)
        return;
    for (ssize_t i = 0; i < n; i++) {
        uint8_t m[2];
        int k = mangle(buf[i], m);
        for (int j = 0; j < k; j++)
            in_q[in_head++ & 0xFFFF] = m[j];
    }
    stats_rx += (uint64_t)n;
    feed_uart();
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

/* ---------------------------------------------------------------- the pty */

static int open_pty(void)
{
    char name[256];
    if (openpty(&master, &slave, name, NULL, NULL) < 0) {
        perror("vtexp-simavr: openpty");
        return -1;
    }
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(master, F_SETFL, O_NONBLOCK);
    printf("port %s\n", name);
    fflush(stdout);
    return 0;
}

static void close_pty(void)
{
    if (master >= 0)
        close(master);
    if (slave >= 0)
        close(slave);
    master = slave = -1;
    in_head = in_tail = out_head = out_tail = 0;
}

/* ---------------------------------------------------------------- commands */

static void command(char *line)
{
    char *nl = strchr(line, '\n');
    if (nl)
        *nl = 0;
    if (!strcmp(line, "mute")) {
        muted = 1;
    } else if (!strcmp(line, "unmute")) {
        muted = 0;
    } else if (!strcmp(line, "unplug")) {
        unplugged = 1;
        close_pty();
    } else if (!strcmp(line, "replug")) {
        close_pty();
        unplugged = 0;
        open_pty();
    } else if (!strcmp(line, "reset")) {
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
    } else if (!strncmp(line, "faults ", 7)) {
        sscanf(line + 7, "%lf %lf %lf", &p_drop, &p_corrupt, &p_insert);
    } else if (!strcmp(line, "flush")) {
        if (trace)
            fflush(trace);
    } else if (!strcmp(line, "quit")) {
        stopping = 1;
    }
    printf("ok %s\n", line);
    fflush(stdout);
}

/* ---------------------------------------------------------------- main */

static void on_signal(int s)
{
    (void)s;
    stopping = 1;
}

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
    if (!value || !lat_raised)
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

static uint64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ULL + (uint64_t)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    const char *elf = NULL, *trace_path = NULL, *profile_path = NULL;
    unsigned long stack_from = 0;
    unsigned long peek_addr[16], peek_len[16];
    int n_peek = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--trace") && i + 1 < argc)
            trace_path = argv[++i];
        else if (!strcmp(argv[i], "--drop") && i + 1 < argc)
            p_drop = atof(argv[++i]);
        else if (!strcmp(argv[i], "--corrupt") && i + 1 < argc)
            p_corrupt = atof(argv[++i]);
        else if (!strcmp(argv[i], "--insert") && i + 1 < argc)
            p_insert = atof(argv[++i]);
        else if (!strcmp(argv[i], "--seed") && i + 1 < argc)
            rng ^= strtoull(argv[++i], NULL, 0) * 0x2545F4914F6CDD1DULL + 1;
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
        else if (argv[i][0] != '-' && !elf)
            elf = argv[i];
        else {
            fprintf(stderr, "vtexp-simavr: unknown argument %s\n", argv[i]);
            return 1;
        }
    }
    if (!elf) {
        fprintf(stderr, "usage: vtexp-simavr FIRMWARE.elf [--trace FILE] [--drop P] "
                        "[--corrupt P] [--insert P] [--seed N] [--fast]\n");
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

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    if (open_pty() != 0)
        return 1;
    trace_line("\"e\":\"start\",\"hz\":%llu", (unsigned long long)MHZ);

    uint64_t t0 = mono_ns(), next_wall = 0;
    char line[256];
    size_t line_n = 0;
    int stdin_open = 1;
    while (!stopping) {
        uint64_t sim_ns = avr->cycle * 1000ULL / (MHZ / 1000000ULL);
        uint64_t wall_ns = mono_ns() - t0;
        int64_t ahead = fast ? 0 : (int64_t)sim_ns - (int64_t)wall_ns;
        if (-ahead > max_lag_ns)
            max_lag_ns = -ahead;
        if (ahead <= 50000) {
            /* run at most 100 us of simulated time, then look at the wall and the pty */
            avr_cycle_count_t until = avr->cycle + MHZ / 10000;
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
        }
        if (sim_ns >= next_wall) {
            trace_line("\"e\":\"wall\",\"ns\":%llu", (unsigned long long)wall_ns);
            if (trace)
                fflush(trace);
            next_wall = sim_ns + 100000000ULL;
        }
        struct pollfd pf[2];
        int nf = 0;
        pf[nf].fd = stdin_open ? 0 : -1;
        pf[nf++].events = POLLIN;
        if (master >= 0) {
            pf[nf].fd = master;
            pf[nf++].events = (short)(POLLIN | (out_tail != out_head ? POLLOUT : 0));
        }
        struct timespec wait = {0, 0};
        if (!fast && ahead > 50000)             /* more than 50 us ahead: let the wall catch up */
            wait.tv_nsec = ahead > 20000000 ? 20000000 : ahead;
        if (ppoll(pf, (nfds_t)nf, &wait, NULL) > 0) {
            if (pf[0].revents & POLLIN) {
                ssize_t r = read(0, line + line_n, sizeof line - 1 - line_n);
                if (r <= 0) {
                    stdin_open = 0;           /* no more commands; run on */
                } else {
                    line_n += (size_t)r;
                    line[line_n] = 0;
                    char *nl;
                    while ((nl = strchr(line, '\n'))) {
                        *nl = 0;
                        command(line);
                        memmove(line, nl + 1, line_n - (size_t)(nl + 1 - line) + 1);
                        line_n = strlen(line);
                    }
                    if (line_n == sizeof line - 1)
                        line_n = 0;
                }
            }
            if (nf > 1 && master >= 0 && (pf[1].revents & POLLIN))
                read_host();
        }
        pump_out();
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
                       "\"worst_pc\":%u,\"worst_vector\":%u,\"hist\":{",
                (unsigned long long)avr->cycle, (unsigned long long)lat_worst,
                (unsigned long long)lat_worst_at, (unsigned)lat_worst_pc, lat_worst_vector);
        const char *sep = "";
        for (int d = 0; d < 128; d++)
            if (lat_hist[d]) {
                fprintf(trace, "%s\"%d\":%llu", sep, d, (unsigned long long)lat_hist[d]);
                sep = ",";
            }
        fputs("}}\n", trace);
    }
    trace_line("\"e\":\"end\",\"rx\":%llu,\"tx\":%llu,\"dropped\":%llu,\"corrupted\":%llu,"
               "\"inserted\":%llu,\"max_lag_ns\":%lld",
               (unsigned long long)stats_rx, (unsigned long long)stats_tx,
               (unsigned long long)stats_dropped, (unsigned long long)stats_corrupted,
               (unsigned long long)stats_inserted, (long long)max_lag_ns);
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
    close_pty();
    fprintf(stderr, "vtexp-simavr: stopped after %.3f s simulated (max lag behind the wall "
                    "clock %.1f ms)\n", (double)avr->cycle / MHZ, (double)max_lag_ns / 1e6);
    return 0;
}
