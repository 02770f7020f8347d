// SPDX-License-Identifier: GPL-3.0-or-later
/* The memory a call may use (spia_options.memory_budget, or what the
 * machine has available now) and the check every entry point makes against
 * it before it allocates what a setting makes grow. */
#if !defined(_WIN32) && !defined(_GNU_SOURCE)
#define _GNU_SOURCE
#endif
#include "internal.h"

#include <stdio.h>
#include <string.h>

#if defined(_WIN32)
#include <windows.h>
#elif defined(__APPLE__)
#include <sys/resource.h>
#include <sys/sysctl.h>
#include <sys/types.h>
#else
#include <sys/resource.h>
#include <unistd.h>
#endif

#if !defined(_WIN32)
/* The address space left under the process's soft RLIMIT_AS, or -1 when
 * there is no such limit (ulimit -v). */
static int64_t address_space_left(void) {
    struct rlimit limit;
    if (getrlimit(RLIMIT_AS, &limit) != 0 || limit.rlim_cur == RLIM_INFINITY) return -1;
    int64_t used = 0;
#if defined(__linux__)
    FILE *f = fopen("/proc/self/statm", "r");
    if (f) {
        long long pages = 0;
        if (fscanf(f, "%lld", &pages) == 1) used = (int64_t)pages * (int64_t)sysconf(_SC_PAGESIZE);
        fclose(f);
    }
#endif
    const int64_t left = (int64_t)limit.rlim_cur - used;
    return left > 0 ? left : 0;
}
#endif

#if defined(__linux__)
/* A "Name:  N kB" line of /proc/meminfo, in bytes, or -1. */
static int64_t meminfo(const char *name) {
    FILE *f = fopen("/proc/meminfo", "r");
    if (!f) return -1;
    char line[256];
    int64_t out = -1;
    const size_t len = strlen(name);
    while (fgets(line, sizeof line, f)) {
        long long kb = 0;
        if (strncmp(line, name, len) == 0 && line[len] == ':' && sscanf(line + len + 1, "%lld", &kb) == 1) {
            out = (int64_t)kb * 1024;
            break;
        }
    }
    fclose(f);
    return out;
}

/* One number from a file (a cgroup's memory.max or memory.current), or -1
 * ("max", absent). */
static int64_t file_number(const char *path) {
    FILE *f = fopen(path, "r");
    if (!f) return -1;
    long long value = -1;
    if (fscanf(f, "%lld", &value) != 1) value = -1;
    fclose(f);
    return (int64_t)value;
}
#endif

static int64_t smaller(int64_t a, int64_t b) {
    if (a < 0) return b;
    if (b < 0) return a;
    return a < b ? a : b;
}

int64_t spia_available_memory(void) {
#if defined(_WIN32)
    MEMORYSTATUSEX s;
    s.dwLength = sizeof s;
    if (!GlobalMemoryStatusEx(&s)) return -1;
    return smaller((int64_t)s.ullAvailPhys, (int64_t)s.ullAvailVirtual);
#elif defined(__APPLE__)
    int64_t total = -1;
    size_t size = sizeof total;
    if (sysctlbyname("hw.memsize", &total, &size, NULL, 0) != 0) total = -1;
    return smaller(total, address_space_left());
#else
    int64_t available = meminfo("MemAvailable");
#if defined(__linux__)
    /* A container's own limit (cgroup v2), where one is set. */
    const int64_t cap = file_number("/sys/fs/cgroup/memory.max"), used = file_number("/sys/fs/cgroup/memory.current");
    if (cap > 0 && used >= 0) available = smaller(available, cap > used ? cap - used : 0);
#endif
    return smaller(available, address_space_left());
#endif
}

int64_t spia__memory_budget(const spia_options *o) {
    if (o->memory_budget > 0) return o->memory_budget;
    if (o->memory_budget < 0) return -1;
    return spia_available_memory();
}

static double gigabytes(double bytes) { return bytes / 1073741824.0; }

spia_result spia__memory_check(const spia_options *o, double need, const char *what, const char *fits,
                               spia_status *status) {
    const int64_t budget = spia__memory_budget(o);
    if (budget < 0 || need <= (double)budget) return SPIA_OK;
    if (o->memory_budget > 0)
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "%s needs about %.2f GB, more than the memory budget of "
                          "%.2f GB%s%s", what, gigabytes(need), gigabytes((double)budget), fits ? ": " : "",
                          fits ? fits : "");
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "%s needs about %.2f GB, more than the %.2f GB of memory available%s%s",
                      what, gigabytes(need), gigabytes((double)budget), fits ? ": " : "", fits ? fits : "");
}

double spia__table_bytes(const spia_mesh *m) {
    /* A limit stencil spans the faces around its vertex: 1 + sum of
     * (size - 2) over them (9 for a regular quad vertex, 7 for a regular
     * triangle one), as 4 + 8 bytes a weight; building it takes up to four
     * times the finished table, and the solvers about 200 bytes a row. */
    double weights = (double)m->vertex_count;
    for (int32_t f = 0; f < m->face_count; ++f) {
        const double k = (double)m->face_sizes[f];
        weights += k * (k > 2.0 ? k - 2.0 : 0.0);
    }
    return 4.0 * 12.0 * weights + 200.0 * (double)m->vertex_count;
}

spia_result spia__memory_check_setting(const spia_options *o, spia__need_fn need, const void *context, int32_t setting,
                                       const char *what, const char *fits_format, const char *nothing_fits,
                                       spia_status *status) {
    const int64_t budget = spia__memory_budget(o);
    if (budget < 0) return SPIA_OK;
    const double bytes = need(context, setting);
    if (bytes <= (double)budget) return SPIA_OK;
    int32_t fit = setting;
    while (fit > 0 && need(context, fit) > (double)budget) --fit;
    char fits[96];
    if (fit > 0)
        snprintf(fits, sizeof fits, fits_format, (int)fit, fit == 1 ? "" : "s");
    else
        snprintf(fits, sizeof fits, "%s", nothing_fits);
    return spia__memory_check(o, bytes, what, fits, status);
}
