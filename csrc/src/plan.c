// SPDX-License-Identifier: GPL-3.0-or-later
/* The sweep layout of a stencil table, for GS_PIA_FAST (see spia_plan in
 * internal.h and fast.c).
 *
 * Gauss-Seidel in vertex order is a chain: each row reads the row swept
 * just before it, so a sweep runs at the speed of one row's latency, on one
 * thread.  The layout here breaks the chain in two ways.  The rows are
 * grouped by the levels of a breadth-first search through the stencils, so
 * that a row refers only to its own level and the two beside it; within a
 * level they are ordered by a colouring of the level, so that the rows
 * swept one after another are not neighbours.  And the levels, gathered in
 * chunks, let a sweep start on the first chunks while the sweep before it
 * is still on later ones: a chunk may be swept again once the chunks it
 * refers to have been, so several sweeps run at once, each on a thread,
 * and do exactly what they would one after another.
 *
 * The layout depends on the table alone, never on the thread count; it is
 * built once, with the table. */
#include "internal.h"
#include "threads.h"

#include <stdlib.h>
#include <string.h>

void spia__plan_free(spia_plan *p) {
    if (!p) return;
    free(p->order);
    free(p->chunk_start);
    free(p->chunk_entry);
    free(p->length);
    free(p->code8);
    free(p->code16);
    free(p->delta16);
    free(p->delta32);
    free(p->weight);
    free(p->weight_f);
    free(p->inverse_f);
    free(p->signed_f);
    free(p);
}

/* ------------------------------------------------------------------------ */
/* The order: breadth-first levels, coloured                                 */
/* ------------------------------------------------------------------------ */

/* The stencils as a graph: row r's own columns and, when in_offsets is
 * set, through the transposed pattern, the rows whose columns hold r too
 * (a boundary vertex's stencil leaves out the interior vertices whose
 * stencils hold it). */
typedef struct graph {
    const spia_stencils *s;
    int64_t *in_offsets; /* rows + 1 */
    int32_t *in_rows;
} graph;

/* in_offsets (rows + 1) and in_rows (at least the table's entries) are
 * the caller's. */
static void graph_build(graph *g, const spia_stencils *s, int64_t *in_offsets, int32_t *in_rows) {
    const int32_t n = s->rows;
    g->s = s;
    g->in_offsets = in_offsets;
    g->in_rows = in_rows;
    memset(in_offsets, 0, sizeof(int64_t) * ((size_t)n + 1));
    for (int32_t r = 0; r < n; ++r)
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k)
            if (s->indices[k] != r) in_offsets[s->indices[k] + 1]++;
    for (int32_t r = 0; r < n; ++r) in_offsets[r + 1] += in_offsets[r];
    /* Filled through the offsets themselves (each ends up at the next
     * row's start), then shifted back. */
    for (int32_t r = 0; r < n; ++r)
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k) {
            const int32_t j = s->indices[k];
            if (j != r) in_rows[in_offsets[j]++] = r;
        }
    for (int32_t r = n; r > 0; --r) in_offsets[r] = in_offsets[r - 1];
    in_offsets[0] = 0;
}

/* Runs `body` for every neighbour u of v (u != v; some twice). */
#define FOR_NEIGHBOURS(g, v, u, body)                                                         \
    do {                                                                                      \
        for (int64_t k_ = (g)->s->offsets[v]; k_ < (g)->s->offsets[(v) + 1]; ++k_) {          \
            const int32_t u = (g)->s->indices[k_];                                            \
            if (u != (v)) body                                                                \
        }                                                                                     \
        if ((g)->in_offsets)                                                                  \
            for (int64_t k_ = (g)->in_offsets[v]; k_ < (g)->in_offsets[(v) + 1]; ++k_) {     \
                const int32_t u = (g)->in_rows[k_];                                           \
                body                                                                          \
            }                                                                                 \
    } while (0)

#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(address) __builtin_prefetch(address)
#else
#define PREFETCH(address) ((void)0)
#endif
/* Rows ahead in the queue whose stencils are fetched early. */
enum { LOOKAHEAD = 8, UNCOLOURED = 0xff };

/* Breadth-first search from `root` through rows whose level is -1, written
 * to queue[begin ..]; returns the end.  Each row is coloured as it leaves
 * the queue: the first colour (of 32; more share the last) that no
 * neighbour of its level has taken, those having left the queue before
 * it. */
static int32_t bfs(const graph *g, int32_t root, int32_t *queue, int32_t begin, int32_t *level, unsigned char *colour) {
    int32_t head = begin, tail = begin;
    queue[tail++] = root;
    level[root] = 0;
    while (head < tail) {
        if (head + 2 * LOOKAHEAD < tail) {
            const int32_t further = queue[head + 2 * LOOKAHEAD];
            PREFETCH(&g->s->offsets[further]);
            if (g->in_offsets) PREFETCH(&g->in_offsets[further]);
        }
        if (head + LOOKAHEAD < tail) {
            const int32_t ahead = queue[head + LOOKAHEAD];
            PREFETCH(&g->s->indices[g->s->offsets[ahead]]);
            if (g->in_offsets) PREFETCH(&g->in_rows[g->in_offsets[ahead]]);
        }
        const int32_t v = queue[head++];
        uint32_t used = 0;
        FOR_NEIGHBOURS(g, v, u, {
            if (level[u] < 0) {
                level[u] = level[v] + 1;
                queue[tail++] = u;
            } else if (level[u] == level[v] && colour[u] != UNCOLOURED) {
                used |= 1u << colour[u];
            }
        });
        int c = 0;
        while (c < 31 && (used >> c & 1u)) ++c;
        colour[v] = (unsigned char)c;
    }
    return tail;
}

/* Scratch room for the plan's build, one block (so that all of it goes
 * back at once): what the search needs, then, in the same room, what
 * filling the plan needs.  The transposed pattern, which only some tables'
 * searches need, is not in it (level_order makes and frees its own), and
 * the column offsets are computed again where they are written rather than
 * kept: the build's peak is the table plus this room plus the plan. */
typedef struct scratch {
    uint16_t *codes;     /* per table entry */
    int32_t *position;   /* per row; NULL in vertex order */
    int32_t *chunk_of;   /* per row; NULL in vertex order */
    /* the search: */
    int32_t *queue;      /* rows */
    unsigned char *colour;
    /* then the filling, in the same room: */
    int64_t *entry;      /* rows + 1 */
} scratch;

static size_t rounded(size_t bytes) { return (bytes + 15) & ~(size_t)15; }

/* The block for a table of n rows and `entries` entries, cut into its
 * arrays; NULL when out of memory. */
static void *scratch_make(scratch *x, size_t n, size_t entries, int levels) {
    const size_t search = levels ? rounded(4 * n) + rounded(n) : 0;
    const size_t filling = rounded(8 * (n + 1));
    const size_t bytes = rounded(2 * entries) + (levels ? 2 * rounded(4 * n) : 0) + (search > filling ? search : filling);
    char *block = (char *)malloc(bytes), *at = block;
    if (!block) return NULL;
    memset(x, 0, sizeof *x);
    x->codes = (uint16_t *)at;
    at += rounded(2 * entries);
    if (levels) {
        x->position = (int32_t *)at;
        at += rounded(4 * n);
        x->chunk_of = (int32_t *)at;
        at += rounded(4 * n);
    }
    char *shared = at;
    if (levels) {
        x->queue = (int32_t *)at;
        at += rounded(4 * n);
        x->colour = (unsigned char *)at;
    }
    x->entry = (int64_t *)shared;
    return block;
}

/* The level order: p->order and p->chunk_start filled; x->chunk_of[r] the
 * chunk of table row r and x->position[r] its position.  The search follows
 * each row's own columns, and with `both_ways` the rows whose columns hold
 * it too.  Returns 0 when out of memory. */
static int level_order(const spia_stencils *s, spia_plan *p, scratch *x, int both_ways) {
    const int32_t n = s->rows;
    graph g;
    memset(&g, 0, sizeof g);
    g.s = s;
    int32_t *queue = x->queue, *chunk_of = x->chunk_of, *position = x->position;
    int32_t *level = chunk_of; /* the level of each row, until it becomes the chunk */
    unsigned char *colour = x->colour;
    free(p->order);
    free(p->chunk_start);
    p->chunk_start = NULL;
    p->order = (int32_t *)malloc(sizeof(int32_t) * (size_t)n);
    int ok = p->order != NULL;
    int64_t *in_offsets = NULL;
    int32_t *in_rows = NULL;
    if (ok && both_ways) {
        in_offsets = (int64_t *)malloc(sizeof(int64_t) * ((size_t)n + 1));
        in_rows = (int32_t *)malloc(sizeof(int32_t) * (size_t)(s->nnz > 0 ? s->nnz : 1));
        ok = in_offsets && in_rows;
        if (ok) graph_build(&g, s, in_offsets, in_rows);
    }
    if (ok) {
        /* Levels from a first row of each connected part, one part after
         * another: rows whose stencils hold only boundary rows are no roots
         * while others are left (the search from one, along its own
         * columns, would stay on its boundary). */
        memset(colour, UNCOLOURED, (size_t)(n > 0 ? n : 0));
        for (int32_t r = 0; r < n; ++r) level[r] = -1;
        int32_t begin = 0, base = 0;
        for (int32_t pick = 0; pick < 2 * n; ++pick) {
            const int32_t root = pick < n ? pick : pick - n;
            if (level[root] >= 0 || (pick < n && s->boundary[root])) continue;
            const int32_t end = bfs(&g, root, queue, begin, level, colour);
            int32_t top = 0;
            for (int32_t q = begin; q < end; ++q) {
                const int32_t v = queue[q];
                if (level[v] > top) top = level[v];
                level[v] += base;
            }
            base += top + 1;
            begin = end;
        }
        /* Each level sorted by colour (stably), and the chunks. */
        int32_t chunks = 0, chunk_rows = 0;
        for (int32_t a = 0; a < n;) {
            int32_t b = a;
            while (b < n && level[queue[b]] == level[queue[a]]) ++b;
            int32_t count[33] = {0};
            for (int32_t q = a; q < b; ++q) count[colour[queue[q]] + 1]++;
            for (int c = 0; c < 32; ++c) count[c + 1] += count[c];
            for (int32_t q = a; q < b; ++q) p->order[a + count[colour[queue[q]]]++] = queue[q];
            if (chunk_rows == 0) ++chunks;
            chunk_rows += b - a;
            if (chunk_rows >= SPIA_PLAN_CHUNK_ROWS) chunk_rows = 0;
            a = b;
        }
        p->chunks = chunks;
        p->chunk_start = (int32_t *)malloc(sizeof(int32_t) * ((size_t)chunks + 1));
        ok = p->chunk_start != NULL;
        if (ok) {
            /* The same walk again, now over the sorted order, writing the
             * chunks, each row's chunk and position. */
            int32_t c = -1;
            chunk_rows = 0;
            for (int32_t a = 0; a < n;) {
                int32_t b = a;
                const int32_t lv = level[p->order[a]];
                while (b < n && level[p->order[b]] == lv) ++b;
                if (chunk_rows == 0) p->chunk_start[++c] = a;
                chunk_rows += b - a;
                if (chunk_rows >= SPIA_PLAN_CHUNK_ROWS) chunk_rows = 0;
                for (int32_t q = a; q < b; ++q) queue[q] = c; /* chunk by position, for now */
                a = b;
            }
            p->chunk_start[chunks] = n;
            for (int32_t q = 0; q < n; ++q) {
                chunk_of[p->order[q]] = queue[q];
                position[p->order[q]] = q;
            }
        }
    }
    free(in_offsets);
    free(in_rows);
    return ok;
}

/* ------------------------------------------------------------------------ */
/* The dictionary of weights                                                 */
/* ------------------------------------------------------------------------ */

enum { DICTIONARY_BITS = 17, DICTIONARY_LIMIT = 32768 }; /* each weight takes two codes */

typedef struct dictionary {
    uint64_t *keys; /* the bits of the weight; 0 (the weight +0.0, never in a table) when empty */
    int32_t *codes;
    double *weight; /* DICTIONARY_LIMIT */
    int32_t count;
} dictionary;

static uint64_t bits_of(double w) {
    uint64_t b;
    memcpy(&b, &w, sizeof b);
    return b;
}

/* The code of w, added if new; -1 past DICTIONARY_LIMIT weights. */
static int32_t dictionary_code(dictionary *d, double w) {
    const uint64_t key = bits_of(w);
    const uint64_t mask = ((uint64_t)1 << DICTIONARY_BITS) - 1;
    uint64_t slot = (key * 0x9E3779B97F4A7C15ull) >> (64 - DICTIONARY_BITS);
    for (;;) {
        if (d->keys[slot] == key) return d->codes[slot];
        if (d->keys[slot] == 0) break;
        slot = (slot + 1) & mask;
    }
    if (d->count >= DICTIONARY_LIMIT) return -1;
    d->keys[slot] = key;
    d->codes[slot] = d->count;
    d->weight[d->count] = w;
    return d->count++;
}

/* The codes of the table's weights, on the threads and the same as one pass
 * in table order would give.  Each range of rows codes its entries with a
 * dictionary of its own (most rows repeat the weights of the row before in
 * the same places: those are looked up there first); the first range's is
 * the plan's.  The other ranges' new weights are then added to it, range
 * after range, so that its codes come in the order the weights first
 * appear in the table, and those ranges' codes are mapped to its. */
enum { CODING_RANGES = 8 };

typedef struct coding {
    const spia_stencils *s;
    uint16_t *codes;
    int32_t ranges;
    dictionary *plan;                    /* the first range's */
    dictionary local[CODING_RANGES];     /* the others' ([0] unused) */
    int32_t *map[CODING_RANGES];         /* their codes to the plan's */
    unsigned char own[CODING_RANGES];    /* every row of the range has a positive own weight */
    unsigned char failed[CODING_RANGES]; /* too many distinct weights */
} coding;

static int32_t range_row(const coding *c, int32_t t) { return (int32_t)((int64_t)c->s->rows * t / c->ranges); }

static void code_ranges(void *context, int64_t t0, int64_t t1, int thread) {
    (void)thread;
    coding *c = (coding *)context;
    const spia_stencils *s = c->s;
    for (int64_t t = t0; t < t1; ++t) {
        dictionary *d = t == 0 ? c->plan : &c->local[t];
        const int32_t first = range_row(c, (int32_t)t), end = range_row(c, (int32_t)t + 1);
        c->own[t] = 1;
        for (int32_t r = first; r < end; ++r) {
            const int64_t b = s->offsets[r], e = s->offsets[r + 1];
            const int64_t before = r > first ? s->offsets[r - 1] : b;
            int own = 0;
            for (int64_t k = b; k < e; ++k) {
                const double w = s->weights[k];
                if (s->indices[k] == r) own = w > 0.0 ? 1 : -1;
                const int64_t same = before + (k - b);
                int32_t code;
                if (same < b && bits_of(s->weights[same]) == bits_of(w))
                    code = c->codes[same];
                else
                    code = dictionary_code(d, w);
                if (code < 0) {
                    c->failed[t] = 1;
                    return;
                }
                c->codes[k] = (uint16_t)code;
            }
            if (own <= 0) c->own[t] = 0; /* no own entry, or not a positive one */
        }
    }
}

static void map_ranges(void *context, int64_t t0, int64_t t1, int thread) {
    (void)thread;
    coding *c = (coding *)context;
    for (int64_t t = t0 > 1 ? t0 : 1; t < t1; ++t) {
        const int32_t *map = c->map[t];
        for (int64_t k = c->s->offsets[range_row(c, (int32_t)t)]; k < c->s->offsets[range_row(c, (int32_t)t + 1)]; ++k)
            c->codes[k] = (uint16_t)map[c->codes[k]];
    }
}

static void coding_free(coding *c) {
    for (int t = 1; t < CODING_RANGES; ++t) {
        free(c->local[t].keys);
        free(c->local[t].codes);
        free(c->local[t].weight);
        free(c->map[t]);
    }
}

/* Fills codes (per table entry) and d, the plan's dictionary (empty, its
 * arrays allocated by the caller); *diagonal_first: every row has a
 * positive own weight.  Returns 1, 0 when out of memory, -1 past
 * DICTIONARY_LIMIT weights. */
static int code_weights(const spia_stencils *s, int threads, uint16_t *codes, dictionary *d, int *diagonal_first) {
    coding c;
    memset(&c, 0, sizeof c);
    c.s = s;
    c.codes = codes;
    c.plan = d;
    c.ranges = threads < CODING_RANGES ? threads : CODING_RANGES;
    if (c.ranges < 1) c.ranges = 1;
    int result = 1;
    for (int32_t t = 1; t < c.ranges && result == 1; ++t) {
        c.local[t].keys = (uint64_t *)calloc((size_t)1 << DICTIONARY_BITS, sizeof(uint64_t));
        c.local[t].codes = (int32_t *)malloc(sizeof(int32_t) * ((size_t)1 << DICTIONARY_BITS));
        c.local[t].weight = (double *)malloc(sizeof(double) * DICTIONARY_LIMIT);
        if (!c.local[t].keys || !c.local[t].codes || !c.local[t].weight) result = 0;
    }
    if (result == 1) spia__parallel_for(c.ranges, c.ranges, 1, code_ranges, &c);
    *diagonal_first = 1;
    for (int32_t t = 0; t < c.ranges && result == 1; ++t) {
        if (c.failed[t]) result = -1;
        if (!c.own[t]) *diagonal_first = 0;
    }
    for (int32_t t = 1; t < c.ranges && result == 1; ++t) {
        const dictionary *local = &c.local[t];
        c.map[t] = (int32_t *)malloc(sizeof(int32_t) * (size_t)(local->count > 0 ? local->count : 1));
        if (!c.map[t]) result = 0;
        for (int32_t j = 0; j < local->count && result == 1; ++j)
            if ((c.map[t][j] = dictionary_code(d, local->weight[j])) < 0) result = -1;
    }
    if (result == 1 && c.ranges > 1) spia__parallel_for(c.ranges, c.ranges, 1, map_ranges, &c);
    coding_free(&c);
    return result;
}

/* ------------------------------------------------------------------------ */
/* The plan                                                                  */
/* ------------------------------------------------------------------------ */

/* The position of table row r, and its chunk. */
typedef struct placing {
    const spia_stencils *s;
    spia_plan *p;
    const int32_t *position, *chunk_of; /* NULL: vertex order, one chunk */
    uint16_t *codes;                    /* per table entry: the dictionary's, then the plan's */
    const int64_t *entry;               /* per position: its first entry in the plan */
    int64_t widest[256];                /* per thread: the largest |column position - row position| */
    int32_t reach[256];                 /* per thread */
    unsigned char unsorted[256];        /* per thread: a row whose columns do not strictly increase */
} placing;

static inline int32_t position_of(const placing *pl, int32_t r) { return pl->position ? pl->position[r] : r; }
static inline int32_t chunk_of(const placing *pl, int32_t r) { return pl->chunk_of ? pl->chunk_of[r] : 0; }

/* The lengths of positions [i0, i1). */
static void length_rows(void *context, int64_t i0, int64_t i1, int thread) {
    (void)thread;
    const placing *pl = (const placing *)context;
    const spia_stencils *s = pl->s;
    spia_plan *p = pl->p;
    for (int64_t i = i0; i < i1; ++i) {
        const int32_t r = p->order ? p->order[i] : (int32_t)i;
        if (p->order && i + 4 * LOOKAHEAD < i1) PREFETCH(&s->offsets[p->order[i + 4 * LOOKAHEAD]]);
        p->length[i] = (uint16_t)(s->offsets[r + 1] - s->offsets[r]);
    }
}

/* The reach over table rows [r0, r1): how many chunks apart a row and a
 * column of its stencil are, at most. */
static void reach_rows(void *context, int64_t r0, int64_t r1, int thread) {
    placing *pl = (placing *)context;
    const spia_stencils *s = pl->s;
    int32_t reach = pl->reach[thread];
    for (int64_t r = r0; r < r1; ++r) {
        const int32_t c = pl->chunk_of[r];
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k) {
            const int32_t cj = pl->chunk_of[s->indices[k]];
            const int32_t apart = cj > c ? cj - c : c - cj;
            if (apart > reach) reach = apart;
        }
    }
    pl->reach[thread] = reach;
}

/* Table rows [r0, r1), in table order: each entry's code (into the second
 * half of the dictionary for the larger off-diagonal weights) and column
 * offset, the offsets' range, the reach and whether every row's columns
 * strictly increase, without a zero weight (then the plan holds the table;
 * see spia__plan_table). */
static void measure_rows(void *context, int64_t r0, int64_t r1, int thread) {
    placing *pl = (placing *)context;
    const spia_stencils *s = pl->s;
    const int32_t edges = pl->p->words / 2;
    int64_t widest = pl->widest[thread];
    int32_t reach = pl->reach[thread];
    for (int64_t r = r0; r < r1; ++r) {
        const int32_t i = position_of(pl, (int32_t)r), c = chunk_of(pl, (int32_t)r);
        double largest = 0.0;
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k)
            if (s->indices[k] != r && s->weights[k] > largest) largest = s->weights[k];
        for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k) {
            const int32_t j = s->indices[k];
            if ((k > s->offsets[r] && j <= s->indices[k - 1]) || s->weights[k] == 0.0) pl->unsorted[thread] = 1;
            if (j != r && s->weights[k] >= 0.5 * largest) pl->codes[k] = (uint16_t)(pl->codes[k] + edges);
            const int64_t delta = (int64_t)position_of(pl, j) - i;
            const int64_t wide = delta > 0 ? delta : -delta;
            if (wide > widest) widest = wide;
            const int32_t apart = chunk_of(pl, j) > c ? chunk_of(pl, j) - c : c - chunk_of(pl, j);
            if (apart > reach) reach = apart;
        }
    }
    pl->widest[thread] = widest;
    pl->reach[thread] = reach;
}

/* Positions [i0, i1) of the plan from their table rows' codes and
 * offsets: the row's own entry first, then the others as the table has
 * them.  (By position, so that threads write apart; the rows a few
 * positions ahead are fetched early.) */
static void place_rows(void *context, int64_t i0, int64_t i1, int thread) {
    (void)thread;
    placing *pl = (placing *)context;
    const spia_stencils *s = pl->s;
    spia_plan *p = pl->p;
    for (int64_t i = i0; i < i1; ++i) {
        const int32_t r = p->order ? p->order[i] : (int32_t)i;
        if (p->order) {
            if (i + 2 * LOOKAHEAD < i1) PREFETCH(&s->offsets[p->order[i + 2 * LOOKAHEAD]]);
            if (i + LOOKAHEAD < i1) {
                const int64_t ahead = s->offsets[p->order[i + LOOKAHEAD]];
                PREFETCH(&pl->codes[ahead]);
                PREFETCH(&s->indices[ahead]);
            }
        }
        int64_t e = pl->entry[i];
        for (int pass = 0; pass < 2; ++pass)
            for (int64_t k = s->offsets[r]; k < s->offsets[r + 1]; ++k) {
                const int32_t j = s->indices[k];
                if ((j == r) != (pass == 0)) continue; /* the row's own entry first */
                const int32_t delta = j == r ? 0 : position_of(pl, j) - (int32_t)i;
                if (p->code8)
                    p->code8[e] = (uint8_t)pl->codes[k];
                else
                    p->code16[e] = pl->codes[k];
                if (p->delta16)
                    p->delta16[e] = (int16_t)delta;
                else
                    p->delta32[e] = delta;
                ++e;
            }
    }
}

/* The first level order and the codes of the weights, each on a thread
 * of its own (items 0 and 1): the two read the table and write apart. */
typedef struct order_coding {
    const spia_stencils *s;
    spia_plan *p;
    scratch *x;
    uint16_t *codes;
    dictionary *d;
    int coded, diagonal_first, ordered;
} order_coding;

static void order_and_code(void *context, int64_t i0, int64_t i1, int thread) {
    (void)thread;
    order_coding *oc = (order_coding *)context;
    for (int64_t i = i0; i < i1; ++i) {
        if (i == 0)
            oc->ordered = level_order(oc->s, oc->p, oc->x, 0);
        else
            oc->coded = code_weights(oc->s, 1, oc->codes, oc->d, &oc->diagonal_first);
    }
}

/* The rows' order in chunks: the order searched along the rows' own
 * columns is searched again both ways (the transposed pattern built) where
 * it leaves rows referring to chunks more than two away; without levels,
 * one chunk.  0 when out of memory. */
static int chunk_order(const spia_stencils *s, spia_plan *p, scratch *x, int threads, int levels) {
    const int32_t n = s->rows;
    if (levels) {
        placing reach;
        memset(&reach, 0, sizeof reach);
        reach.s = s;
        reach.chunk_of = x->chunk_of;
        spia__parallel_for(threads, n, 0, reach_rows, &reach);
        int32_t apart = 0;
        for (int t = 0; t < threads; ++t)
            if (reach.reach[t] > apart) apart = reach.reach[t];
        if (apart > 2 && !level_order(s, p, x, 1)) return 0;
    } else {
        p->chunks = 1;
        p->chunk_start = (int32_t *)malloc(sizeof(int32_t) * 2);
        if (!p->chunk_start) return 0;
        p->chunk_start[0] = 0;
        p->chunk_start[1] = n;
    }
    return 1;
}

/* Lengths and where each position's entries start (the search's room is
 * the filling's now).  0 when out of memory. */
static int entry_starts(const spia_stencils *s, spia_plan *p, scratch *x, int threads) {
    const int32_t n = s->rows;
    int64_t *entry = x->entry;
    p->length = (uint16_t *)malloc(sizeof(uint16_t) * (size_t)(n > 0 ? n : 1));
    p->chunk_entry = (int64_t *)malloc(sizeof(int64_t) * ((size_t)p->chunks + 1));
    if (!p->length || !p->chunk_entry) return 0;
    {
        placing pl;
        memset(&pl, 0, sizeof pl);
        pl.s = s;
        pl.p = p;
        spia__parallel_for(threads, n, 0, length_rows, &pl);
    }
    entry[0] = 0;
    for (int32_t i = 0; i < n; ++i) entry[i + 1] = entry[i] + p->length[i];
    for (int32_t c = 0; c <= p->chunks; ++c) p->chunk_entry[c] = entry[p->chunk_start[c]];
    return 1;
}

/* Codes and offsets, at their widths: each of the `count` weights has two
 * codes, as itself and where it is one of the larger off-diagonal weights
 * of its row (the first step's edges).  0 when out of memory. */
static int codes_and_offsets(const spia_stencils *s, spia_plan *p, const scratch *x, uint16_t *codes, int32_t count,
                             int threads, size_t entries) {
    const int32_t n = s->rows;
    int64_t *entry = x->entry;
    p->words = 2 * count;
    placing pl;
    memset(&pl, 0, sizeof pl);
    pl.s = s;
    pl.p = p;
    pl.position = x->position;
    pl.chunk_of = x->chunk_of;
    pl.codes = codes;
    pl.entry = entry;
    spia__parallel_for(threads, n, 0, measure_rows, &pl);
    int64_t widest = 0;
    p->holds_table = 1;
    for (int t = 0; t < threads; ++t) {
        if (pl.widest[t] > widest) widest = pl.widest[t];
        if (pl.reach[t] > p->reach) p->reach = pl.reach[t];
        if (pl.unsorted[t]) p->holds_table = 0;
    }
    if (widest <= 32767)
        p->delta16 = (int16_t *)malloc(sizeof(int16_t) * entries);
    else
        p->delta32 = (int32_t *)malloc(sizeof(int32_t) * entries);
    if (p->words <= 256)
        p->code8 = (uint8_t *)malloc(entries);
    else
        p->code16 = (uint16_t *)malloc(sizeof(uint16_t) * entries);
    if ((!p->delta16 && !p->delta32) || (!p->code8 && !p->code16)) return 0;
    spia__parallel_for(threads, n, 0, place_rows, &pl);
    return 1;
}

/* The weights of the codes, in double and in float, their inverses and
 * their signed copies.  0 when out of memory. */
static int weight_tables(spia_plan *p, const dictionary *d) {
    const size_t words = (size_t)(p->words > 0 ? p->words : 1);
    p->weight = (double *)malloc(sizeof(double) * words);
    p->weight_f = (float *)malloc(sizeof(float) * words);
    p->inverse_f = (float *)malloc(sizeof(float) * words);
    p->signed_f = (float *)malloc(sizeof(float) * words);
    if (!p->weight || !p->weight_f || !p->inverse_f || !p->signed_f) return 0;
    for (int32_t c = 0; c < p->words; ++c) {
        const double w = d->weight[c % d->count];
        p->weight[c] = w;
        p->weight_f[c] = (float)w;
        p->inverse_f[c] = (float)(1.0 / w);
        p->signed_f[c] = c < d->count ? (float)w : -(float)w;
    }
    return 1;
}

spia_result spia__plan_build(spia_stencils *s, int threads, spia_status *status) {
    const int32_t n = s->rows;
    s->plan = NULL;
    if (threads < 1) threads = 1;
    if (threads > 256) threads = 256;
    if (n < SPIA_PARALLEL_ROWS) threads = 1;
    for (int32_t r = 0; r < n; ++r)
        if (s->offsets[r + 1] - s->offsets[r] > 65535) return SPIA_OK; /* no plan: GS_PIA_FAST falls back */
    const size_t entries = (size_t)(s->nnz > 0 ? s->nnz : 1);
    const int levels = n >= SPIA_PARALLEL_ROWS;
    spia_plan *p = (spia_plan *)calloc(1, sizeof *p);
    scratch x;
    void *block = p ? scratch_make(&x, (size_t)n, entries, levels) : NULL;
    dictionary d;
    memset(&d, 0, sizeof d);
    if (!block) goto out_of_memory;
    p->rows = n;
    uint16_t *codes = x.codes;

    /* The distinct weights, coded in the order they first appear. */
    d.keys = (uint64_t *)calloc((size_t)1 << DICTIONARY_BITS, sizeof(uint64_t));
    d.codes = (int32_t *)malloc(sizeof(int32_t) * ((size_t)1 << DICTIONARY_BITS));
    d.weight = (double *)malloc(sizeof(double) * DICTIONARY_LIMIT);
    if (!d.keys || !d.codes || !d.weight) goto out_of_memory;
    {
        /* With levels and threads, the first order is searched on one
         * thread while another codes the weights. */
        order_coding oc = {s, p, &x, codes, &d, 0, 0, 1};
        if (levels && threads > 1) {
            spia__parallel_for(2, 2, 1, order_and_code, &oc);
        } else {
            oc.coded = code_weights(s, threads, codes, &d, &oc.diagonal_first);
            if (levels) oc.ordered = level_order(s, p, &x, 0);
        }
        const int coded = oc.coded, diagonal_first = oc.diagonal_first;
        if (coded == 0 || !oc.ordered) goto out_of_memory;
        if (coded < 0) {
            /* Too many distinct weights (shape parameters per face, say):
             * no plan. */
            free(d.keys);
            free(d.codes);
            free(d.weight);
            free(block);
            spia__plan_free(p);
            return SPIA_OK;
        }
        p->diagonal_first = diagonal_first;
    }
    free(d.keys);
    free(d.codes);
    d.keys = NULL;
    d.codes = NULL;

    if (!chunk_order(s, p, &x, threads, levels)) goto out_of_memory;

    if (!entry_starts(s, p, &x, threads)) goto out_of_memory;
    if (!codes_and_offsets(s, p, &x, codes, d.count, threads, entries)) goto out_of_memory;
    free(block);
    block = NULL;

    if (!weight_tables(p, &d)) goto out_of_memory;
    free(d.weight);
    s->plan = p;
    return SPIA_OK;

out_of_memory:
    free(d.keys);
    free(d.codes);
    free(d.weight);
    free(block);
    spia__plan_free(p);
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory laying out the stencils for the solver");
}

/* ------------------------------------------------------------------------ */
/* The table, from the plan                                                  */
/* ------------------------------------------------------------------------ */

static inline int32_t plan_delta(const spia_plan *p, int64_t k) { return p->delta16 ? p->delta16[k] : p->delta32[k]; }
static inline double plan_weight(const spia_plan *p, int64_t k) {
    return p->weight[p->code8 ? p->code8[k] : p->code16[k]];
}
static inline int32_t plan_column(const spia_plan *p, int32_t i, int64_t k) {
    const int32_t at = i + plan_delta(p, k);
    return p->order ? p->order[at] : at;
}

/* Position i's entries (from entry e on) in the table's order.  The plan
 * has the row's own entry first (the only one with offset 0) and the others
 * as the table had them, by increasing column; `slot` is where the own
 * entry goes back among them (-1: the row has none). */
typedef struct plan_row {
    int64_t e;
    int32_t length, slot, row;
} plan_row;

static plan_row row_at(const spia_plan *p, int32_t i, int64_t e) {
    plan_row w = {e, p->length[i], -1, p->order ? p->order[i] : i};
    if (w.length > 0 && plan_delta(p, e) == 0) {
        int32_t lo = 0, hi = w.length - 1; /* the first other entry of a larger column */
        while (lo < hi) {
            const int32_t mid = lo + (hi - lo) / 2;
            if (plan_column(p, i, e + 1 + mid) < w.row)
                lo = mid + 1;
            else
                hi = mid;
        }
        w.slot = lo;
    }
    return w;
}

/* The plan entry of the row's t-th entry in the table. */
static inline int64_t entry_of(const plan_row *w, int32_t t) {
    return w->slot < 0 || t > w->slot ? w->e + t : t < w->slot ? w->e + 1 + t : w->e;
}

typedef struct table_task {
    const spia_plan *p;
    const int64_t *offsets;
    int32_t *indices;
    double *weights;
} table_task;

/* The rows of chunks [c0, c1) (each row written where its offset says, so
 * that chunks on different threads write apart). */
static void table_chunks(void *context, int64_t c0, int64_t c1, int thread) {
    (void)thread;
    const table_task *t = (const table_task *)context;
    const spia_plan *p = t->p;
    for (int64_t c = c0; c < c1; ++c) {
        int64_t e = p->chunk_entry[c];
        for (int32_t i = p->chunk_start[c]; i < p->chunk_start[c + 1]; ++i) {
            const plan_row w = row_at(p, i, e);
            const int64_t base = t->offsets[w.row];
            for (int32_t k = 0; k < w.length; ++k) {
                const int64_t at = entry_of(&w, k);
                if (t->indices) t->indices[base + k] = plan_column(p, i, at);
                if (t->weights) t->weights[base + k] = plan_weight(p, at);
            }
            e += w.length;
        }
    }
}

void spia__plan_table(const spia_plan *p, int64_t *offsets, int32_t *indices, double *weights, int threads) {
    const int32_t n = p->rows;
    offsets[0] = 0;
    for (int32_t i = 0; i < n; ++i) offsets[(p->order ? p->order[i] : i) + 1] = p->length[i];
    for (int32_t r = 0; r < n; ++r) offsets[r + 1] += offsets[r];
    if (!indices && !weights) return;
    table_task t = {p, offsets, indices, weights};
    spia__parallel_for(n >= SPIA_PARALLEL_ROWS ? threads : 1, p->chunks, 1, table_chunks, &t);
}

void spia__plan_apply(const spia_plan *p, const double *cage, double *out) {
    int64_t e = 0;
    for (int32_t i = 0; i < p->rows; ++i) {
        const plan_row w = row_at(p, i, e);
        double a = 0.0, b = 0.0, c = 0.0; /* as spia__row_product, in the table's order */
        for (int32_t t = 0; t < w.length; ++t) {
            const int64_t k = entry_of(&w, t);
            const double x = plan_weight(p, k);
            const double *q = cage + 3 * (int64_t)plan_column(p, i, k);
            a += x * q[0];
            b += x * q[1];
            c += x * q[2];
        }
        double *o = out + 3 * (int64_t)w.row;
        o[0] = a;
        o[1] = b;
        o[2] = c;
        e += w.length;
    }
}
