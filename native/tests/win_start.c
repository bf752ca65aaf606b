/* harness.exe's start on Windows without MinGW-w64's C runtime (which zig would first build from
 * source, minutes from a cold cache): the entry point, argv and printf / fprintf, from the universal
 * C runtime that every Windows 10+ has (ucrtbase.dll), as the kernels' DLL links it (native/build.py,
 * WINDOWS_LINK).  Linked into the Windows harness only (tests/native/conftest.py). */

#include <corecrt_startup.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

int main(int argc, char **argv);

void __main(void) {} /* clang calls it first thing in main on MinGW targets, to run constructors: none */

/* The UCRT exports the formatting behind printf, not printf itself (its headers inline these). */
int fprintf(FILE *f, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    int n = __stdio_common_vfprintf(0, f, fmt, NULL, args);
    va_end(args);
    return n;
}

int printf(const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    int n = __stdio_common_vfprintf(0, stdout, fmt, NULL, args);
    va_end(args);
    return n;
}

void mainCRTStartup(void)
{
    _configure_narrow_argv(_crt_argv_unexpanded_arguments);
    exit(main(*__p___argc(), *__p___argv())); /* exit flushes and closes the streams */
}
