// SPDX-License-Identifier: GPL-3.0-or-later
/* A bounding volume hierarchy over triangles, for nearest-triangle queries
 * (the closest points on a scan, scan.c).  Private to the library. */
#ifndef SPIA_BVH_H
#define SPIA_BVH_H

#include "subdiv_pia.h"
#include "threads.h"

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* No tree is deeper than this: below depth 64 (in halvings) the builder
 * stops looking for good splits and halves each range, which reaches a leaf
 * within 32 more.  A query's stack is sized from it. */
#define SPIA__BVH_MAX_DEPTH 128

/* A node of up to four children: their boxes (float, holding their
 * triangles' vertices exactly), side by side for the four at once, and for
 * each either a node (count 0: nodes[child]) or a leaf (count > 0: the
 * triangles child .. child + count - 1 in leaf order).  128 bytes (two
 * 64-byte lines); node 0 is the root. */
typedef struct spia__bvh_node {
    float lo[3][4]; /* lo[axis][child] */
    float hi[3][4];
    uint32_t child[4];
    uint8_t count[4];
    uint32_t children; /* 1 (a root that is a leaf) to 4 */
    uint32_t unused[2];
} spia__bvh_node;

typedef struct spia__bvh {
    spia__bvh_node *nodes;
    int64_t node_count;
    /* order[i] is the index that triangle i (in leaf order) had before the
     * build: the tie-break among triangles at equal distance. */
    uint32_t *order;
    const float *positions;   /* borrowed: 3 floats per vertex                      */
    const int32_t *triangles; /* borrowed: 3 vertex indices per triangle, leaf order */
    int64_t triangle_count;
    int32_t depth;            /* levels of nodes below the root                      */
    double extent;            /* the largest |coordinate| of a triangle's vertex     */
    void *node_memory;        /* nodes, before alignment                             */
} spia__bvh;

/* Builds the hierarchy over triangle_count (>= 1, < 2^32) triangles of
 * `triangles` (3 indices each into `positions`, 3 finite floats each),
 * sorting `triangles` in place into leaf order (bvh->order says where each
 * came from).  Both arrays are borrowed and must outlive the hierarchy.
 * Binned surface-area heuristic; the top levels and then the subtrees are
 * built on `threads` threads (the tree does not depend on their number).
 * Fails only with SPIA_ERROR_OUT_OF_MEMORY; then *bvh is zeroed, the
 * triangles are in their first order and nothing is left allocated. */
spia_result spia__bvh_build(spia__bvh *bvh, const float *positions, int32_t *triangles, int64_t triangle_count,
                            int threads, spia_status *status);

/* The progress of a long build (a scan's): the caller's callback, called
 * on the calling thread only (thread 0 of the parallel loops), at most
 * every `interval` seconds, with `phase` and the fraction of the whole
 * build done.  A nonzero return cancels: `cancelled` is raised, and every
 * thread stops at its next poll. */
typedef struct spia__build_progress {
    spia_progress_fn fn; /* NULL: never called, never cancelled */
    void *user_data;
    int32_t phase;
    double interval, last;
    double from, to; /* the part of the whole that the phase under way spans */
    spia__counter cancelled;
} spia__build_progress;

/* Polls p from thread `thread` with the phase `fraction` done: calls the
 * callback when on thread 0 and the interval has passed.  Nonzero when the
 * build is cancelled (now or before).  p may be NULL. */
int spia__build_poll(spia__build_progress *p, int thread, double fraction);

/* spia__scan_closest_points_double (internal.h) polling `progress` (may be
 * NULL) every 256 points: for a long query (a fit's round on a large
 * scan) that a caller wants to be able to cancel.  Returns nonzero when
 * cancelled, the outputs then partly written.  Defined in scan.c. */
int spia__scan_closest_points_polled(const spia_scan *s, int64_t count, const double *points,
                                     const float *radius, int32_t *near, float *closest, float *normals,
                                     float *distances, int32_t *faces, uint8_t *on_boundary, int threads,
                                     spia__build_progress *progress);

/* spia__bvh_build polling `progress` (which may be NULL) from every thread;
 * fails also with SPIA_ERROR_CANCELLED, leaving nothing allocated and the
 * triangles in their first order. */
spia_result spia__bvh_build_progress(spia__bvh *bvh, const float *positions, int32_t *triangles,
                                     int64_t triangle_count, int threads, spia__build_progress *progress,
                                     spia_status *status);

/* spia__bvh_build_progress handing the build's working memory (28 bytes a
 * triangle, its pages already faulted in) to the caller instead of freeing
 * it: *scratch (the caller frees it) of *scratch_bytes bytes, NULL and 0
 * when the build fails. */
spia_result spia__bvh_build_keep(spia__bvh *bvh, const float *positions, int32_t *triangles, int64_t triangle_count,
                                 int threads, spia__build_progress *progress, void **scratch, size_t *scratch_bytes,
                                 spia_status *status);
void spia__bvh_free(spia__bvh *bvh);

/* After the borrowed positions have moved (the triangles and their order
 * staying), gives every node the boxes of its children again, from the
 * leaves up, and the extent: the tree is valid for the new positions (its
 * queries as exact as ever), though no longer shaped for them.  Cheap
 * beside a build (a pass over the triangles and the nodes). */
void spia__bvh_refit(spia__bvh *bvh);

/* The bytes the hierarchy holds (nodes and order; not the borrowed arrays). */
size_t spia__bvh_bytes(const spia__bvh *bvh);

typedef struct spia__bvh_hit {
    int64_t triangle; /* in leaf order (bvh->triangles + 3 * triangle); -1 if none */
    double d2;        /* squared distance, as spia__triangle_distance2 computes it */
    double bary[3];   /* the closest point's weights of the triangle's corners      */
    double point[3];  /* the closest point                                          */
} spia__bvh_hit;

/* The triangle nearest to p: the least squared distance computed by
 * spia__triangle_distance2, and among equal ones the lowest index before the
 * build; exactly what a search over every triangle finds.  `radius` is a
 * hint (INFINITY for none): triangles farther than it are not looked at,
 * and when none is within it every triangle is.  So the hit never depends
 * on the hint, only the time does.  The hit's triangle is -1 only when p
 * is not finite. */
void spia__bvh_closest(const spia__bvh *bvh, const double p[3], double radius, spia__bvh_hit *hit);

/* The same hit as spia__bvh_closest, the search starting from triangle
 * `start` (in leaf order, as a hit names it; ignored when out of range):
 * its distance bounds the search from the first step.  For a point that
 * moved a little since its last search, that triangle's distance is
 * nearly the answer, and far tighter than any radius known beforehand. */
void spia__bvh_closest_from(const spia__bvh *bvh, const double p[3], int64_t start, spia__bvh_hit *hit);

/* The closest point to p on triangle (a, b, c): its barycentric weights of
 * a, b, c, the point, and the squared distance; in double.  A triangle
 * without area is the union of its edges. */
double spia__triangle_distance2(const double p[3], const float *a, const float *b, const float *c, double bary[3],
                                double point[3]);

#ifdef __cplusplus
}
#endif

#endif
