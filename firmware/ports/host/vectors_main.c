/* vtexp-fw-vectors: the vector runner on the host, on stdin and stdout. */
#include <stdio.h>

#include "vt_runner.h"

int vt_runner_getc(void) { return getchar(); }

void vt_runner_putc(char c)
{
    putchar(c);
    if (c == '\n')
        fflush(stdout);
}

int main(void)
{
    vt_runner_run();
    return 0;
}
