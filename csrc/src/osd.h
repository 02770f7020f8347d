// SPDX-License-Identifier: GPL-3.0-or-later
// What the OpenSubdiv path shares among its files (osd_*.cpp): limit
// stencils, refinement and sample stencils from OpenSubdiv.  Catmull-Clark
// is set up exactly as Blender's Subdivision Surface modifier sets it up when
// "Use Limit Surface" is on, so that the limit points these stencils give
// are the points the modifier shows for the control vertices.  Loop (with
// OpenSubdiv's boundary rules) goes through the same path with the Blender
// specific rules left out, at the exact limit.
//
// What Blender does, and so what this file does:
//  - vertices used by no face are left out of the OpenSubdiv topology and
//    keep their position (identity stencil);
//  - edge and vertex creases c in [0, 1] become sharpness c*c*10 (float);
//    end points of loose edges become infinitely sharp; a vertex with
//    exactly two incident edges gets the smaller of their sharpnesses added
//    to its own, capped at 10;
//  - boundary_smooth ALL / PRESERVE_CORNERS are VTX_BOUNDARY_EDGE_ONLY /
//    EDGE_AND_CORNER, creasing CREASE_UNIFORM;
//  - adaptive refinement with isolation level = quality and infinitely
//    sharp patches, limit evaluated at the control vertex's corner of the
//    first face (in face order) that uses it;
//  - where Blender's patches give the exact limit point anyway and it has a
//    closed form, the row comes from catmark_closed.c, and OpenSubdiv's
//    refiner is built only on the faces around the other vertices; among
//    those, where the patches give the exact limit, Bfr gives the same
//    stencil directly (see step 5);
//  - with spia_options.opensubdiv_version above 30600, the non-manifold
//    vertices that OpenSubdiv after 3.6.0 sharpens are sharpened (step 4b);
//  - samples inside the faces (for fitting) come from Bfr face by face,
//    and from the adaptive patch table only around the corners Bfr does not
//    reproduce (surface_blocks, at the end).
//
// The steps, by file: 1 to 4 osd_sharpness.cpp; the parts of the mesh with
// refiners of their own osd_parts.cpp; 5 osd_evaluation.cpp; 6a, 6b and 6c
// osd_rings.cpp; 7 osd_batches.cpp (Loop's rows in osd_loop_fans.cpp);
// 8 to 11 and the table osd_limit_stencils.cpp; uniform refinement
// osd_refine.cpp; samples inside the faces osd_samples.cpp.  Everything
// here is in namespace spia_osd and hidden (the library exports spia_*
// alone).
#ifndef SPIA_OSD_H
#define SPIA_OSD_H

#include "internal.h"
#include "threads.h"

#include <opensubdiv/bfr/refinerSurfaceFactory.h>
#include <opensubdiv/bfr/surface.h>
#include <opensubdiv/far/patchMap.h>
#include <opensubdiv/far/patchTableFactory.h>
#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/error.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <algorithm>
#include <atomic>
#include <climits>
#include <cmath>
#include <cstring>
#include <memory>
#include <new>
#include <type_traits>
#include <vector>

namespace spia_osd {

using namespace OpenSubdiv;

typedef std::pair<int32_t, double> Entry;  // column, weight

const float kInfiniteSharpness = Sdc::Crease::SHARPNESS_INFINITE;  // 10

// spia__parallel_for with a lambda f(begin, end, thread), which must not throw.
template <class F>
void parallel_for(int threads, int64_t count, int64_t grain, F &&f) {
    typedef typename std::remove_reference<F>::type Fn;
    spia__parallel_for(threads, count, grain,
                       [](void *context, int64_t begin, int64_t end, int thread) {
                           (*static_cast<Fn *>(context))(begin, end, thread);
                       },
                       (void *)&f);
}

// Blender's crease-to-sharpness mapping, in float as Blender computes it.
inline float crease_to_sharpness(float crease) { return crease * crease * 10.0f; }

// Steps 1 to 3 below, shared by the stencils and by refinement: Blender's
// (or, for Loop, OpenSubdiv's) sharpness values, and the renumbering that
// leaves out unused vertices ("osd" numbering).  Step 4 makes a refiner of
// the whole mesh (refinement, samples) or of the part of it around the
// vertices that need OpenSubdiv's patches (stencils, see Part).
struct Prepared {
    int32_t osd_n = 0;
    std::vector<int32_t> osd_of, vertex_of, remapped;
    std::vector<int32_t> crease_pairs, corner_indices;
    std::vector<float> crease_weights, corner_weights;
    // The same sharpness in the mesh's own numbering, for the closed-form
    // rows (catmark_closed.c): per vertex, and each vertex's creased face
    // edges as a list (empty when no edge is creased).
    std::vector<float> vertex_sharpness;
    std::vector<int64_t> crease_first;
    std::vector<int32_t> crease_other;
    std::vector<float> crease_sharpness;
    bool blender = false;
    Sdc::SchemeType scheme = Sdc::SCHEME_CATMARK;
    Sdc::Options sdc;
    std::unique_ptr<Far::TopologyRefiner> refiner;  // the whole mesh (prepare())
};

spia_result prepare_sharpness(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                              bool two_edge_rule = true);
Far::TopologyRefiner *create_refiner(int32_t vertex_count, int32_t face_count, const int32_t *face_sizes,
                                     const int32_t *face_vertices, const std::vector<int32_t> &crease_pairs,
                                     const std::vector<float> &crease_weights,
                                     const std::vector<int32_t> &corner_indices,
                                     const std::vector<float> &corner_weights, Sdc::SchemeType scheme,
                                     const Sdc::Options &sdc);

// 4. A refiner for the given topology and sharpness (in its own numbering).
//    Blender with OpenSubdiv after 3.6.0: the non-manifold vertices that
//    version sharpens and this one (3.5 or 3.6.0) does not get infinite
//    sharpness of their own, and the refiner is made again.  The vertices
//    stay non-manifold, so their rows come from adaptive patches, where
//    their limit point is the vertex itself.  `sharpened` receives them.
Far::TopologyRefiner *make_refiner(const Prepared &p, const spia_options *opt, int32_t vertex_count,
                                   int32_t face_count, const int32_t *face_sizes, const int32_t *fv,
                                   const std::vector<int32_t> &crease_pairs, const std::vector<float> &crease_weights,
                                   std::vector<int32_t> &corner_indices, std::vector<float> &corner_weights,
                                   std::vector<int32_t> *sharpened);
// Steps 1 to 4 for the whole mesh.
spia_result prepare(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                    spia_status *status);

// (index, weight) pairs sorted and repeated indices added up (in sorted
// order, so the sums do not depend on how the pairs came); zero sums are
// dropped when asked.
template <class I>
void merge_entries(std::vector<std::pair<I, double>> &v, bool drop_zeros) {
    std::sort(v.begin(), v.end());
    size_t out = 0;
    for (size_t i = 0; i < v.size();) {
        const I j = v[i].first;
        double sum = 0.0;
        while (i < v.size() && v[i].first == j) sum += v[i++].second;
        if (!drop_zeros || sum != 0.0) v[out++] = std::make_pair(j, sum);
    }
    v.resize(out);
}

// A sparse stencil for Far::PrimvarRefiner: weights over control vertices.
struct SparseStencil {
    std::vector<std::pair<int32_t, double>> w;
    void Clear(void * = nullptr) { w.clear(); }
    // Weights from PrimvarRefinerReal<float> (Loop) or <double>.
    void AddWithWeight(const SparseStencil &src, double weight) {
        for (const auto &e : src.w) w.emplace_back(e.first, weight * e.second);
    }
    void Compact() { merge_entries(w, false); }
};

// Runs run(b) for batches 0 .. count - 1 on the threads (at most one per
// batch).  Out of memory anywhere is thrown again here; another exception
// is passed to failed(b).
template <class Run, class Failed>
void run_batches(int threads, int32_t count, Run &&run, Failed &&failed) {
    std::atomic<bool> out_of_memory(false);
    parallel_for(std::max(1, std::min(threads, (int)count)), count, 1, [&](int64_t b0, int64_t b1, int) {
        for (int64_t b = b0; b < b1; ++b) {
            try {
                run((int32_t)b);
            } catch (const std::bad_alloc &) {
                out_of_memory = true;
            } catch (...) {
                failed((int32_t)b);
            }
        }
    });
    if (out_of_memory) throw std::bad_alloc();
}

// Items 0 .. count-1 in the Morton order of their points (point(i): three
// floats) within the points' box, ties in item order.
template <class PointOf>
std::vector<int32_t> morton_order(int32_t count, PointOf point) {
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int32_t i = 0; i < count; ++i)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], point(i)[a]);
            hi[a] = std::max(hi[a], point(i)[a]);
        }
    auto spread = [](uint64_t x) {  // 21 bits to every third of 63
        x &= 0x1fffff;
        x = (x | x << 32) & 0x1f00000000ffffULL;
        x = (x | x << 16) & 0x1f0000ff0000ffULL;
        x = (x | x << 8) & 0x100f00f00f00f00fULL;
        x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
        x = (x | x << 2) & 0x1249249249249249ULL;
        return x;
    };
    std::vector<std::pair<uint64_t, int32_t>> keyed((size_t)count);
    for (int32_t i = 0; i < count; ++i) {
        uint64_t key = 0;
        for (int a = 0; a < 3; ++a) {
            const double t = hi[a] > lo[a] ? ((double)point(i)[a] - lo[a]) / ((double)hi[a] - lo[a]) : 0.0;
            key |= spread((uint64_t)std::min(2097151.0, std::max(0.0, t * 2097151.0))) << a;
        }
        keyed[(size_t)i] = std::make_pair(key, i);
    }
    std::sort(keyed.begin(), keyed.end());
    std::vector<int32_t> order((size_t)count);
    for (int32_t i = 0; i < count; ++i) order[(size_t)i] = keyed[(size_t)i].second;
    return order;
}

// A part of the mesh with an OpenSubdiv refiner of its own, and the maps
// between its numbering and the osd numbering (identities, left empty, when
// it is the whole mesh in the mesh's order).
struct Part {
    std::unique_ptr<Far::TopologyRefiner> refiner;
    bool whole = true;
    std::vector<int32_t> local_of, osd_of_local;  // vertices
    std::vector<int32_t> mesh_face_of;           // local face -> mesh face
    std::vector<int32_t> sizes, fv;              // its topology
    std::vector<int32_t> crease_pairs, corner_indices;
    std::vector<float> crease_weights, corner_weights;
    int32_t vertex(int32_t o) const { return whole ? o : local_of[(size_t)o]; }
    int32_t osd(int32_t i) const { return whole ? i : osd_of_local[(size_t)i]; }
    int32_t mesh_face(int32_t i) const { return whole ? i : mesh_face_of[(size_t)i]; }
};

// The faces within two rings of the marked osd vertices: their limit points
// depend on their own faces alone, and the second ring gives those faces'
// vertices complete neighbourhoods (so their rules are the whole mesh's).
std::vector<char> two_ring_faces(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                                 const std::vector<int32_t> &marked);
// The part of the mesh made of the faces in_part (all when in_part is
// empty).  Vertices the refiner sharpens after 3.6.0 (make_refiner) are
// sharpened in p as well, so that the sub-meshes of step 7 see them.
//    The sub-meshes of step 7 (`own` false) take p's sharpness as it is.
spia_result make_part(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                      const std::vector<char> &in_part, bool own, const unsigned char *one_fan, Part &part,
                      spia_status *status);
// The osd vertices of `list` in the order of the part's numbering (which
// follows its faces, part_face_order): walking the part's refiner in that
// order keeps its memory near.  For the loops whose results do not depend
// on the order.
std::vector<int32_t> in_part_order(const Part &part, const std::vector<int32_t> &list);

// Rows kept aside until the table exists, in osd numbering of the vertex and
// mesh numbering of the columns.
struct HeldRows {
    std::vector<int64_t> start;  // per osd vertex, -1 for none
    std::vector<int32_t> size;
    std::vector<int32_t> indices;
    std::vector<double> weights;
    // Vertex o's row from (osd column, weight) entries.
    template <class Entries>
    void hold(const Prepared &p, int32_t o, const Entries &entries) {
        if (start.empty()) {
            start.assign((size_t)p.osd_n, -1);
            size.assign((size_t)p.osd_n, 0);
        }
        start[(size_t)o] = (int64_t)indices.size();
        for (const auto &e : entries) {
            indices.push_back(p.vertex_of[(size_t)e.first]);
            weights.push_back(e.second);
        }
        size[(size_t)o] = (int32_t)((int64_t)indices.size() - start[(size_t)o]);
    }
};

// How each vertex that needs OpenSubdiv is evaluated (step 5).
struct Evaluation {
    std::vector<char> adaptive;       // per osd vertex: step 7's level for it, 0 for none
    std::vector<int32_t> bfr_corner;  // per osd vertex: the corner Bfr evaluates it at (step 10), or -1
    std::vector<char> level_face;     // per mesh face: Bfr at the isolation level (empty if none)
    std::vector<int32_t> ring;        // non-manifold osd vertices taken from their crease (step 6c)
    std::vector<int32_t> levels;      // and how many levels deep
    int32_t adaptive_count = 0;
};

// The one ring of a manifold vertex: face j lies between its edges a[j]
// and b[j]; edge i has one face (boundary) or two.
struct Ring {
    int32_t centre = -1;
    std::vector<int32_t> far_end;        // per edge: its other vertex
    std::vector<float> sharpness;        // per edge (boundary: infinite)
    std::vector<int32_t> a, b;           // per face: its two edges at the centre
    std::vector<int32_t> edge_face;      // per edge: two faces, the second -1 on the boundary
    std::vector<int32_t> faces;          // per face: the mesh's face
};

struct RingScratch {
    std::vector<float> sharpness, child;
    std::vector<double> vertex_masks, edge_masks, g, next, centre_of_face;
};

// The row of the ring's centre at `levels` levels, over the mesh's
// vertices; false where a mask is not of the kind expected.
bool ring_row(const spia_mesh *m, const spia_adjacency *adj, const Ring &ring, float vertex_sharpness, int levels,
              const Sdc::Options &sdc, RingScratch &s, std::vector<Entry> &row);
// Step 6a's ring of vertex v read from the mesh (see osd_rings.cpp).
int fan_ring(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const spia_catmark_sharpness &sh,
             const spia_options *opt, int32_t v, bool boundary, std::vector<int32_t> &next, std::vector<int32_t> &prev,
             Ring &ring);
// Whether step 6c takes v (Catmull-Clark as Blender sets it up), and how
// many levels deep: none for an infinitely sharp vertex, `depth` (at most
// the isolation level) for a span between the two edges, the isolation
// level for a span ending twice at one.
bool nonmanifold_levels(const Far::TopologyLevel &base, Far::Index v, int depth, int quality, int &levels);
// 6c, on the threads: each non-manifold vertex's row from its crease.
spia_result ring_rows(const spia_options *opt, const Prepared &p, const Part &part, const Evaluation &ev,
                      HeldRows &held, spia_status *status);

// 5. How each vertex of `wanted` (osd numbering) is evaluated.  At
//    semi-sharp features and darts of manifold meshes Blender's surface
//    depends on the isolation level.  Semi-sharp vertices of manifold fans
//    have their row from their one ring already (steps 6a, 6b) and do not
//    come here.  At darts and the other
//    semi-sharp vertices Bfr with its approximation
//    levels (sharp and smooth) set to `quality` builds the same patches as
//    Blender's adaptive refinement at that level, evaluated at the vertex's
//    corner of its first face as Blender does.  Non-manifold vertices that
//    are infinitely sharp or on a non-manifold crease take their row from
//    the crease (step 6c).  The other non-manifold vertices and
//    smooth valence-2 boundary corners go through the adaptive
//    LimitStencilTableFactory, on their neighbourhood only, as Blender
//    builds it (Bfr does not reproduce those).  Where the limit point has a
//    closed form Blender's patches reproduce it exactly; those vertices
//    that come here (Loop, and Catmull-Clark ones whose fan the closed form
//    does not take) get Bfr at its default levels.  The test against the
//    full adaptive table (tests/c/test_reference.cpp, with random creases
//    on scans) holds all of this to 1e-12.
void choose_evaluation(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, const Prepared &p,
                       const Part &part, const std::vector<int32_t> &wanted, Evaluation &ev);

// A batch's rows, or the failure that stopped it.
struct BatchRows {
    std::vector<int32_t> vertex;  // osd numbering, one per row
    std::vector<int64_t> start;   // rows' first entries, plus the end
    std::vector<int32_t> indices; // osd numbering
    std::vector<double> weights;
    spia_result code = SPIA_OK;
    int64_t index = -1;
    char message[SPIA_MESSAGE_SIZE] = {0};

    void begin_row(int32_t o) {
        vertex.push_back(o);
        start.push_back((int64_t)indices.size());
    }
    void add(int32_t column, double weight) {
        indices.push_back(column);
        weights.push_back(weight);
    }
    void end() { start.push_back((int64_t)indices.size()); }
    void failed(spia_result code_, int64_t index_, const char *text, int value, int value2) {
        code = code_;
        index = index_;
        snprintf(message, sizeof message, text, value, value2);
    }
};

// Loop is taken at its exact limit: each vertex refined on its own fan
// until its semi-sharp features have decayed, then OpenSubdiv's limit
// masks (fan_limit_rows), on sparse stencils.
void loop_batch_rows(const Part &sub, const std::vector<int32_t> &marked, const Prepared &p, BatchRows &out);
// Step 7 (osd_batches.cpp): the vertices ev marks adaptive, into held.
spia_result adaptive_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                          const Evaluation &ev, HeldRows &held, spia_status *status);

}  // namespace spia_osd

#endif
