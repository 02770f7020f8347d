// SPDX-License-Identifier: GPL-3.0-or-later
// The library's only C++ file: limit stencils from OpenSubdiv.  Catmull-Clark
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

using namespace OpenSubdiv;

namespace {

// OpenSubdiv reports errors and warnings by printing them unless callbacks
// are set; the library never prints (it returns codes and messages).  Its
// OpenSubdiv is its own, linked in statically with its names hidden, so
// setting them once when the library is loaded, before any thread of the
// host can call in, touches no other OpenSubdiv.
struct QuietOpenSubdiv {
    QuietOpenSubdiv() {
        Far::SetErrorCallback([](Far::ErrorType, const char *) {});
        Far::SetWarningCallback([](const char *) {});
    }
} quiet_opensubdiv;

typedef Far::LimitStencilTableFactoryReal<double> LimitFactory;
typedef std::pair<int32_t, double> Entry;  // column, weight

const float kInfiniteSharpness = Sdc::Crease::SHARPNESS_INFINITE;  // 10
// Feature vertices per adaptive sub-mesh, and the most sub-meshes (step 7).
const int32_t kFeatureBatch = 250, kMaxFeatureBatches = 64;
// Faces per Bfr factory (step 10): its cache of irregular patches lives that long.
const int32_t kFaceBlock = 131072;
// A part of at least this many faces is taken in spatial order when its
// faces, in the mesh's order, are on average this far apart (against the
// diagonal): part_face_order.
const int32_t kScatteredPartFaces = 4096;
const double kScatteredStep = 0.05;

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

// True when a and b are consecutive corners of some face.
bool is_face_edge(const spia_mesh *m, const spia_adjacency *adj, int32_t a, int32_t b) {
    for (int64_t i = adj->first[a]; i < adj->first[a + 1]; ++i) {
        int64_t c = adj->corner_of[i];
        if (spia__corner_next(m, adj, c) == b || spia__corner_prev(m, adj, c) == b) return true;
    }
    return false;
}

// Each vertex's creased edges, as (other end, sharpness) lists from
// first[v] on, merged where an edge is listed more than once (either way
// round) into one entry of its largest sharpness, in place.  Returns
// whether any was.  (pos[u]: where u's entry is in the list being merged,
// if at or after that list's start.)
bool merge_repeated_creases(int32_t n, std::vector<int64_t> &first, std::vector<int32_t> &other,
                            std::vector<float> &sharpness) {
    std::vector<int64_t> pos((size_t)n, -1);
    bool repeated = false;
    int64_t out = 0;
    for (int32_t v = 0; v < n; ++v) {
        const int64_t begin = first[v], end = first[v + 1], start = out;
        first[v] = out;
        for (int64_t i = begin; i < end; ++i) {
            const int32_t u = other[(size_t)i];
            if (pos[(size_t)u] >= start) {
                repeated = true;
                float &kept = sharpness[(size_t)pos[(size_t)u]];
                kept = std::max(kept, sharpness[(size_t)i]);
                continue;
            }
            pos[(size_t)u] = out;
            other[(size_t)out] = u;
            sharpness[(size_t)out++] = sharpness[(size_t)i];
        }
    }
    first[(size_t)n] = out;
    other.resize((size_t)out);
    sharpness.resize((size_t)out);
    return repeated;
}

// A Catmull-Clark refiner for a face list, with Blender's sharpness values.
// OpenSubdiv's TopologyRefinerFactory::Create holds the new refiner in a
// plain pointer while it fills in the base level, so the refiner is lost
// when an allocation there throws; this one owns it until it is complete.
struct OwningRefinerFactory : Far::TopologyRefinerFactory<Far::TopologyDescriptor> {
    static Far::TopologyRefiner *Create(const Far::TopologyDescriptor &mesh, Options options) {
        std::unique_ptr<Far::TopologyRefiner> refiner(new Far::TopologyRefiner(options.schemeType, options.schemeOptions));
        if (!populateBaseLevel(*refiner, mesh, options)) return nullptr;
        return refiner.release();
    }
};

Far::TopologyRefiner *create_refiner(int32_t vertex_count, int32_t face_count, const int32_t *face_sizes,
                                     const int32_t *face_vertices, const std::vector<int32_t> &crease_pairs,
                                     const std::vector<float> &crease_weights,
                                     const std::vector<int32_t> &corner_indices,
                                     const std::vector<float> &corner_weights, Sdc::SchemeType scheme,
                                     const Sdc::Options &sdc) {
    Far::TopologyDescriptor desc;
    desc.numVertices = vertex_count;
    desc.numFaces = face_count;
    desc.numVertsPerFace = face_sizes;
    desc.vertIndicesPerFace = face_vertices;
    desc.numCreases = (int)crease_weights.size();
    desc.creaseVertexIndexPairs = crease_pairs.empty() ? nullptr : crease_pairs.data();
    desc.creaseWeights = crease_weights.empty() ? nullptr : crease_weights.data();
    desc.numCorners = (int)corner_weights.size();
    desc.cornerVertexIndices = corner_indices.empty() ? nullptr : corner_indices.data();
    desc.cornerWeights = corner_weights.empty() ? nullptr : corner_weights.data();
    return OwningRefinerFactory::Create(desc, OwningRefinerFactory::Options(scheme, sdc));
}

// OpenSubdiv 3.6.0 leaves a non-manifold vertex smooth when it has exactly
// two non-manifold edges, no boundary edge and more faces than edges,
// taking it for a vertex on a non-manifold crease (sheets meeting along a
// line); later versions (3.7.0, Blender 5.1 and later) sharpen it unless it
// really is one: the two edges have as many faces, every other edge has
// two, and the faces around the vertex form fans each running, face to
// face across manifold edges, from one of the two edges to the other.  A
// fan that returns to the edge it started from (a double-sided fin hanging
// from one edge) fails the test.  This is OpenSubdiv's test
// (Vtr::Level::testVertexNonManifoldCrease), walked on the refiner's base
// level, whose edge and face orders are the ones it walks.
bool on_nonmanifold_crease(const Far::TopologyLevel &base, Far::Index v) {
    Far::Index crease[2] = {-1, -1};
    Far::ConstIndexArray ve = base.GetVertexEdges(v);
    for (int i = 0; i < ve.size(); ++i) {
        if (base.IsEdgeNonManifold(ve[i])) {
            if (crease[1] >= 0) return false;
            crease[crease[0] >= 0] = ve[i];
        } else if (base.GetEdgeFaces(ve[i]).size() != 2) {
            return false;
        }
    }
    if (crease[1] < 0 || base.GetEdgeFaces(crease[0]).size() != base.GetEdgeFaces(crease[1]).size()) return false;
    int walked = 0;
    for (int i = 0; i < 2; ++i) {
        const Far::Index start = crease[i], end = crease[1 - i];
        Far::ConstIndexArray ef = base.GetEdgeFaces(start);
        Far::ConstLocalIndexArray in_face = base.GetEdgeFaceLocalIndices(start);
        for (int j = 0; j < ef.size(); ++j) {
            // Each fan is walked from the end where its edge leaves the vertex.
            if (base.GetFaceVertices(ef[j])[in_face[j]] != v) continue;
            Far::Index e = start, f = ef[j];
            while (e != end) {
                if (e != start) {
                    Far::ConstIndexArray pair = base.GetEdgeFaces(e);
                    f = pair[pair[0] == f ? 1 : 0];
                }
                ++walked;
                Far::ConstIndexArray fe = base.GetFaceEdges(f);
                int k = 0;
                while (k < fe.size() && fe[k] != e) ++k;
                if (k == fe.size()) return false;  // not expected
                e = fe[k ? k - 1 : fe.size() - 1];  // the face's other edge at v
                if (e == start) return false;
            }
        }
    }
    return walked == base.GetVertexFaces(v).size();
}

// The vertices that OpenSubdiv after 3.6.0 makes infinitely sharp and 3.6.0
// does not (see on_nonmanifold_crease).
std::vector<int32_t> sharpened_after_360(const Far::TopologyLevel &base) {
    std::vector<int32_t> out;
    for (Far::Index v = 0; v < base.GetNumVertices(); ++v) {
        if (!base.IsVertexNonManifold(v) || base.GetVertexSharpness(v) >= kInfiniteSharpness) continue;
        Far::ConstIndexArray ve = base.GetVertexEdges(v);
        int non_manifold = 0, boundary = 0;
        for (int i = 0; i < ve.size(); ++i) {
            non_manifold += base.IsEdgeNonManifold(ve[i]) ? 1 : 0;
            boundary += base.GetEdgeFaces(ve[i]).size() < 2 ? 1 : 0;
        }
        // 3.6.0's own condition for leaving the vertex smooth (the vertex is
        // not infinitely sharp, so it held), checked again all the same.
        const bool taken_for_crease = non_manifold == 2 && boundary == 0 && base.GetVertexFaces(v).size() > ve.size();
        if (taken_for_crease && !on_nonmanifold_crease(base, v)) out.push_back((int32_t)v);
    }
    return out;
}

// Steps 1 to 3 below, shared by the stencils and by refinement: Blender's
// (or, for Loop, OpenSubdiv's) sharpness values, and the renumbering that
// leaves out unused vertices ("osd" numbering).  Step 4 makes a refiner of
// the whole mesh (refinement, samples) or of the part of it around the
// vertices that need OpenSubdiv's patches (stencils, see Region).
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
                              bool two_edge_rule = true) {
    const int32_t n = m->vertex_count;
    const bool use_creases = !opt->ignore_creases;
    // Blender's own rules (loose-edge ends, the two-edge rule, smooth corners
    // off the limit) apply to Catmull-Clark, which Blender evaluates; Loop
    // follows OpenSubdiv alone and is evaluated at the exact limit.
    const bool blender = opt->scheme == SPIA_SCHEME_CATMULL_CLARK;
    const Sdc::SchemeType scheme = blender ? Sdc::SCHEME_CATMARK : Sdc::SCHEME_LOOP;

    // 1. Vertices used by faces, renumbered densely in vertex order.
    std::vector<int32_t> osd_of(n, -1), vertex_of;
    vertex_of.reserve(n);
    for (int32_t v = 0; v < n; ++v) {
        if (adj->first[v + 1] > adj->first[v]) {
            osd_of[v] = (int32_t)vertex_of.size();
            vertex_of.push_back(v);
        }
    }
    const int32_t osd_n = (int32_t)vertex_of.size();
    const bool renumbered = osd_n != n;
    std::vector<int32_t> remapped;
    if (renumbered) {
        remapped.resize((size_t)adj->corner_count);
        for (int64_t c = 0; c < adj->corner_count; ++c) remapped[c] = osd_of[m->face_vertices[c]];
    }

    // 2. Edge sharpness of face edges; loose edges sharpen their end points.
    std::vector<float> vertex_sharpness(osd_n, 0.0f);
    std::vector<int32_t> crease_pairs;
    std::vector<float> crease_weights;
    // Per vertex, the number of its creased face edges, then (counting
    // sort) the edges themselves as (other end, sharpness) lists.
    std::vector<int64_t> crease_first;
    for (int pass = 0; pass < 2; ++pass) {
        std::vector<int64_t> fill;
        if (pass == 1) {
            if (crease_first.empty()) break;
            for (int32_t v = 0; v < n; ++v) crease_first[v + 1] += crease_first[v];
            fill.assign(crease_first.begin(), crease_first.end() - 1);
            p.crease_other.resize((size_t)crease_first[n]);
            p.crease_sharpness.resize((size_t)crease_first[n]);
        }
        for (int32_t e = 0; e < m->edge_count; ++e) {
            int32_t a = m->edges[2 * (int64_t)e], b = m->edges[2 * (int64_t)e + 1];
            bool face_edge = osd_of[a] >= 0 && osd_of[b] >= 0 && is_face_edge(m, adj, a, b);
            if (!face_edge) {
                if (!blender || pass == 1) continue;
                if (osd_of[a] >= 0) vertex_sharpness[osd_of[a]] = INFINITY;
                if (osd_of[b] >= 0) vertex_sharpness[osd_of[b]] = INFINITY;
                continue;
            }
            if (!use_creases || !m->edge_creases) continue;
            float s = crease_to_sharpness(m->edge_creases[e]);
            if (s < 1e-6f) continue;
            if (pass == 0) {
                if (crease_first.empty()) crease_first.assign((size_t)n + 1, 0);
                crease_pairs.push_back(osd_of[a]);
                crease_pairs.push_back(osd_of[b]);
                crease_weights.push_back(s);
                ++crease_first[a + 1];
                ++crease_first[b + 1];
            } else {
                p.crease_other[(size_t)fill[a]] = b;
                p.crease_sharpness[(size_t)fill[a]++] = s;
                p.crease_other[(size_t)fill[b]] = a;
                p.crease_sharpness[(size_t)fill[b]++] = s;
            }
        }
    }
    // An edge listed more than once takes its largest crease: the lists
    // merged, the pairs for OpenSubdiv are made again from them.
    if (!crease_first.empty() && merge_repeated_creases(n, crease_first, p.crease_other, p.crease_sharpness)) {
        crease_pairs.clear();
        crease_weights.clear();
        for (int32_t a = 0; a < n; ++a)
            for (int64_t i = crease_first[(size_t)a]; i < crease_first[(size_t)a + 1]; ++i) {
                const int32_t b = p.crease_other[(size_t)i];
                if (a > b) continue;
                crease_pairs.push_back(osd_of[(size_t)a]);
                crease_pairs.push_back(osd_of[(size_t)b]);
                crease_weights.push_back(p.crease_sharpness[(size_t)i]);
            }
    }
    const bool any_edge_crease = !crease_first.empty();

    // 3. Vertex sharpness: infinite at loose-edge ends; else the vertex
    //    crease, plus the smaller sharpness of exactly two incident edges.
    std::vector<int32_t> corner_indices;
    std::vector<float> corner_weights;
    p.vertex_sharpness.assign((size_t)n, 0.0f);
    for (int32_t o = 0; o < osd_n; ++o) {
        int32_t v = vertex_of[o];
        float s;
        if (vertex_sharpness[o] == INFINITY) {
            s = kInfiniteSharpness;
        } else {
            s = (use_creases && m->vertex_creases) ? crease_to_sharpness(m->vertex_creases[v]) : 0.0f;
            if (blender && two_edge_rule && any_edge_crease && crease_first[v + 1] > crease_first[v]) {
                // Distinct neighbours along face edges.
                int32_t nb[3];
                int count = 0;
                for (int64_t i = adj->first[v]; i < adj->first[v + 1] && count < 3; ++i) {
                    int64_t c = adj->corner_of[i];
                    int32_t cand[2] = {spia__corner_prev(m, adj, c), spia__corner_next(m, adj, c)};
                    for (int32_t w : cand) {
                        bool seen = false;
                        for (int k = 0; k < count; ++k) seen = seen || nb[k] == w;
                        if (!seen && count < 3) nb[count++] = w;
                    }
                }
                if (count == 2) {
                    float e_s[2] = {0.0f, 0.0f};
                    for (int k = 0; k < 2; ++k)
                        for (int64_t i = crease_first[v]; i < crease_first[v + 1]; ++i)
                            if (p.crease_other[(size_t)i] == nb[k]) e_s[k] = p.crease_sharpness[(size_t)i];
                    s += std::min(e_s[0], e_s[1]);
                    s = std::min(s, 10.0f);
                }
            }
        }
        if (s > 0.0f) {
            corner_indices.push_back(o);
            corner_weights.push_back(s);
        }
        p.vertex_sharpness[(size_t)v] = s;
    }

    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS
                                        ? Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER
                                        : Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    sdc.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    sdc.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);
    p.osd_n = osd_n;
    p.osd_of.swap(osd_of);
    p.vertex_of.swap(vertex_of);
    p.remapped.swap(remapped);
    p.crease_pairs.swap(crease_pairs);
    p.crease_weights.swap(crease_weights);
    p.corner_indices.swap(corner_indices);
    p.corner_weights.swap(corner_weights);
    p.crease_first.swap(crease_first);
    p.blender = blender;
    p.scheme = scheme;
    p.sdc = sdc;
    return SPIA_OK;
}

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
                                   std::vector<int32_t> *sharpened) {
    std::unique_ptr<Far::TopologyRefiner> refiner(create_refiner(vertex_count, face_count, face_sizes, fv, crease_pairs,
                                                                 crease_weights, corner_indices, corner_weights,
                                                                 p.scheme, p.sdc));
    if (!refiner || !p.blender || opt->opensubdiv_version <= 30600) return refiner.release();
    const std::vector<int32_t> more = sharpened_after_360(refiner->GetLevel(0));
    if (more.empty()) return refiner.release();
    std::vector<int32_t> corner_of((size_t)vertex_count, -1);
    for (size_t k = 0; k < corner_indices.size(); ++k) corner_of[(size_t)corner_indices[k]] = (int32_t)k;
    for (int32_t o : more) {
        if (corner_of[(size_t)o] >= 0) {
            corner_weights[(size_t)corner_of[(size_t)o]] = kInfiniteSharpness;
        } else {
            corner_indices.push_back(o);
            corner_weights.push_back(kInfiniteSharpness);
        }
    }
    if (sharpened) *sharpened = more;
    return create_refiner(vertex_count, face_count, face_sizes, fv, crease_pairs, crease_weights, corner_indices,
                          corner_weights, p.scheme, p.sdc);
}

// Steps 1 to 4 for the whole mesh.
spia_result prepare(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                    spia_status *status) {
    spia_result r = prepare_sharpness(m, adj, opt, p);
    if (r != SPIA_OK) return r;
    p.refiner.reset(make_refiner(p, opt, p.osd_n, m->face_count, m->face_sizes,
                                 p.remapped.empty() ? m->face_vertices : p.remapped.data(), p.crease_pairs,
                                 p.crease_weights, p.corner_indices, p.corner_weights, nullptr));
    if (!p.refiner) return spia__fail(status, SPIA_ERROR_TOPOLOGY, -1, "OpenSubdiv rejected the mesh topology");
    return SPIA_OK;
}

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

// One level down: the entries of row with indices in [begin, end) replaced
// by those points' stencils in `step` (over the level below, whose points
// start at `below`), the others kept; then merged, zero sums dropped.
template <class I>
void carry_down(std::vector<std::pair<I, double>> &row, const std::vector<SparseStencil> &step, I begin, I end,
                I below, std::vector<std::pair<I, double>> &scratch) {
    scratch.clear();
    for (const auto &e : row) {
        if (e.first >= begin && e.first < end) {
            for (const auto &x : step[(size_t)(e.first - begin)].w)
                scratch.emplace_back(below + (I)x.first, e.second * x.second);
        } else {
            scratch.push_back(e);
        }
    }
    merge_entries(scratch, true);
    row.swap(scratch);
}

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

// Loop's exact limit at a vertex depends on its faces alone: the points of
// its one ring one level down (its child and the children of its edges)
// are combinations of the points of its one ring, under rules that read
// only the sharpness of its edges and of itself.  So each vertex is refined
// on a copy of its own fan, one level at a time, each level's fan taken
// from the refinement of the last, until its semi-sharp features have
// decayed, and OpenSubdiv's limit mask is applied there: a few dozen points
// a level whatever the sharpness, where refining the whole mesh that deep
// makes four times its faces a level.  The fans of a batch's vertices are
// refined together, as one mesh of disjoint fans.
struct Fans {
    std::vector<int32_t> sizes, fv;
    std::vector<int32_t> crease_pairs, corner_indices;
    std::vector<float> crease_weights, corner_weights;
    std::vector<SparseStencil> points;  // per fan vertex, over the sub-mesh's control vertices
    std::vector<int32_t> centre, owner;  // per fan: its centre (a fan vertex) and whose fan it is

    // Appends the fan of vertex c of `level`, whose points are `pts`.
    void add(const Far::TopologyLevel &level, Far::Index c, const SparseStencil *pts, int32_t whose,
             std::vector<std::pair<Far::Index, int32_t>> &local) {
        local.clear();
        auto vertex = [&](Far::Index v) {
            for (const auto &e : local)
                if (e.first == v) return e.second;
            const int32_t i = (int32_t)points.size();
            local.emplace_back(v, i);
            points.push_back(pts[v]);
            return i;
        };
        const int32_t mid = vertex(c);
        centre.push_back(mid);
        owner.push_back(whose);
        Far::ConstIndexArray faces = level.GetVertexFaces(c);
        for (int k = 0; k < faces.size(); ++k) {
            Far::ConstIndexArray corners = level.GetFaceVertices(faces[k]);
            sizes.push_back(corners.size());
            for (int j = 0; j < corners.size(); ++j) fv.push_back(vertex(corners[j]));
        }
        Far::ConstIndexArray edges = level.GetVertexEdges(c);
        for (int k = 0; k < edges.size(); ++k) {
            const float s = level.GetEdgeSharpness(edges[k]);
            if (s <= 0.0f) continue;
            Far::ConstIndexArray ends = level.GetEdgeVertices(edges[k]);
            crease_pairs.push_back(vertex(ends[0]));
            crease_pairs.push_back(vertex(ends[1]));
            crease_weights.push_back(s);
        }
        const float s = level.GetVertexSharpness(c);
        if (s > 0.0f) {
            corner_indices.push_back(mid);
            corner_weights.push_back(s);
        }
    }
};

// Levels until the semi-sharp features at vertex v of `level` have
// decayed (at least one, at most ten).
int decay_levels(const Far::TopologyLevel &level, Far::Index v) {
    float sharpest = level.GetVertexSharpness(v);
    if (sharpest >= kInfiniteSharpness) sharpest = 0.0f;
    Far::ConstIndexArray edges = level.GetVertexEdges(v);
    for (int k = 0; k < edges.size(); ++k) {
        const float s = level.GetEdgeSharpness(edges[k]);
        if (s < kInfiniteSharpness) sharpest = std::max(sharpest, s);
    }
    return std::max(1, std::min(10, (int)std::ceil(sharpest)));
}

// Rows of the exact limit (refinement until the semi-sharp features have
// decayed, then limit masks) for `marked` (osd numbering), vertices of the
// sub-mesh refiner `sub` (local_of: osd -> sub vertex), over its control
// vertices; add_row(o, stencil) receives each.  The memory grows with the
// vertices' fans and the levels, not with four to the levels.
template <class AddRow>
bool fan_limit_rows(const Far::TopologyRefiner &sub, const std::vector<int32_t> &marked,
                    const std::vector<int32_t> &local_of, Sdc::SchemeType scheme, const Sdc::Options &sdc,
                    AddRow add_row) {
    const Far::TopologyLevel &base = sub.GetLevel(0);
    std::vector<SparseStencil> identity((size_t)base.GetNumVertices());
    for (int32_t i = 0; i < base.GetNumVertices(); ++i) identity[(size_t)i].w.emplace_back(i, 1.0);
    std::vector<int> levels(marked.size());
    std::vector<std::pair<Far::Index, int32_t>> local;
    Fans fans;
    for (size_t i = 0; i < marked.size(); ++i) {
        const Far::Index v = local_of[(size_t)marked[i]];
        levels[i] = decay_levels(base, v);
        fans.add(base, v, identity.data(), (int32_t)i, local);
    }
    std::vector<SparseStencil>().swap(identity);
    for (int level = 1; !fans.owner.empty(); ++level) {
        std::unique_ptr<Far::TopologyRefiner> refiner(create_refiner(
            (int32_t)fans.points.size(), (int32_t)fans.sizes.size(), fans.sizes.data(), fans.fv.data(),
            fans.crease_pairs, fans.crease_weights, fans.corner_indices, fans.corner_weights, scheme, sdc));
        if (!refiner) return false;
        Far::TopologyRefiner::UniformOptions uniform(1);
        uniform.fullTopologyInLastLevel = true;
        refiner->RefineUniform(uniform);
        const Far::TopologyLevel &parent = refiner->GetLevel(0), &child = refiner->GetLevel(1);
        std::vector<SparseStencil> refined((size_t)child.GetNumVertices());
        Far::PrimvarRefinerReal<double> primvar(*refiner);
        SparseStencil *src = fans.points.data(), *dst = refined.data();
        primvar.Interpolate(1, src, dst);
        for (SparseStencil &st : refined) st.Compact();
        std::vector<SparseStencil> limit;
        bool any_done = false;
        for (int32_t owner : fans.owner) any_done = any_done || levels[(size_t)owner] == level;
        if (any_done) {
            limit.resize(refined.size());
            SparseStencil *limit_dst = limit.data();
            primvar.Limit(dst, limit_dst);
        }
        Fans next;
        for (size_t k = 0; k < fans.owner.size(); ++k) {
            const int32_t owner = fans.owner[k];
            const Far::Index c = parent.GetVertexChildVertex(fans.centre[k]);
            if (levels[(size_t)owner] == level) {
                SparseStencil &st = limit[(size_t)c];
                st.Compact();
                add_row(marked[(size_t)owner], st);
            } else {
                next.add(child, c, refined.data(), owner, local);
            }
        }
        std::swap(fans, next);
    }
    return true;
}

// The sharpness of a part of the mesh, in a numbering of its own (local_of:
// osd vertex -> local vertex, -1 outside): the creased edges the part's
// faces have (OpenSubdiv warns about others) and the sharp vertices in it.
void restrict_sharpness(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                        const std::vector<int32_t> &local_of, const std::vector<char> &in_part,
                        std::vector<int32_t> &pairs, std::vector<float> &weights, std::vector<int32_t> &corners,
                        std::vector<float> &corner_weights) {
    for (size_t k = 0; k < p.crease_weights.size(); ++k) {
        int32_t a = p.crease_pairs[2 * k], b = p.crease_pairs[2 * k + 1];
        if (local_of[a] < 0 || local_of[b] < 0) continue;
        bool present = false;
        int32_t va = p.vertex_of[a];
        for (int64_t i = adj->first[va]; i < adj->first[va + 1] && !present; ++i) {
            int64_t c = adj->corner_of[i];
            present = in_part[adj->face_of_corner[c]] &&
                      (p.osd_of[spia__corner_next(m, adj, c)] == b || p.osd_of[spia__corner_prev(m, adj, c)] == b);
        }
        if (!present) continue;
        pairs.push_back(local_of[a]);
        pairs.push_back(local_of[b]);
        weights.push_back(p.crease_weights[k]);
    }
    for (size_t k = 0; k < p.corner_weights.size(); ++k) {
        if (local_of[p.corner_indices[k]] < 0) continue;
        corners.push_back(local_of[p.corner_indices[k]]);
        corner_weights.push_back(p.corner_weights[k]);
    }
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

// The faces within two rings of the marked osd vertices: their limit points
// depend on their own faces alone, and the second ring gives those faces'
// vertices complete neighbourhoods (so their rules are the whole mesh's).
std::vector<char> two_ring_faces(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                                 const std::vector<int32_t> &marked) {
    std::vector<char> near_vertex((size_t)p.osd_n, 0), in_part((size_t)m->face_count, 0);
    for (int32_t o : marked) {
        int32_t v = p.vertex_of[o];
        for (int64_t k = adj->first[v]; k < adj->first[v + 1]; ++k) {
            int32_t f = adj->face_of_corner[adj->corner_of[k]];
            for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c)
                near_vertex[p.osd_of[m->face_vertices[c]]] = 1;
        }
    }
    for (int32_t o = 0; o < p.osd_n; ++o) {
        if (!near_vertex[o]) continue;
        int32_t v = p.vertex_of[o];
        for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) in_part[adj->face_of_corner[adj->corner_of[i]]] = 1;
    }
    return in_part;
}

// The order in which a part's refiner takes its faces: the mesh's (empty
// result), except where that order scatters a large part over the whole
// mesh, as in files written in random order.  Building the refiner and
// walking its rings then wait on memory at every face, about half the time
// of the shuffled dragon scan with creases on 30% of its edges.  There the
// faces go in the Morton order of their first vertices instead, except the
// faces of vertices that are not one consistently oriented fan (one_fan[v]
// neither 0 nor 1: non-manifold, or not classified): OpenSubdiv's rules at
// those depend on the order of their faces (the first face's span, step
// 6c), so those faces come first, in the mesh's order.  Around the other
// vertices only the face Far starts their rings from changes, which no row
// taken from the refiner reads (the semi-sharp fans, whose crease masks
// would, take their rings from the mesh, 6a): the rows are those of the
// mesh's order (test_reference, 1e-12; the hard set's tables to the bit).
std::vector<int32_t> part_face_order(const spia_mesh *m, const spia_adjacency *adj, const std::vector<char> &in_part,
                                     const unsigned char *one_fan) {
    std::vector<int32_t> faces;
    if (!one_fan) return faces;
    for (int32_t f = 0; f < m->face_count; ++f)
        if (in_part.empty() || in_part[(size_t)f]) faces.push_back(f);
    if ((int32_t)faces.size() < kScatteredPartFaces) return std::vector<int32_t>();
    auto first_point = [&](int32_t f) { return m->positions + 3 * (int64_t)m->face_vertices[adj->corner_start[f]]; };
    // Mean step from face to face against the box's diagonal.
    double step = 0.0, lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < faces.size(); ++i) {
        const float *x = first_point(faces[i]);
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], (double)x[a]);
            hi[a] = std::max(hi[a], (double)x[a]);
        }
        if (i > 0) {
            const float *y = first_point(faces[i - 1]);
            step += std::sqrt(((double)x[0] - y[0]) * ((double)x[0] - y[0]) + ((double)x[1] - y[1]) * ((double)x[1] - y[1]) +
                              ((double)x[2] - y[2]) * ((double)x[2] - y[2]));
        }
    }
    const double diagonal =
        std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2]));
    if (!(step > kScatteredStep * diagonal * (double)(faces.size() - 1))) return std::vector<int32_t>();
    std::vector<int32_t> kept, free_faces;
    for (int32_t f : faces) {
        bool keep = false;
        for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1] && !keep; ++c)
            keep = one_fan[m->face_vertices[c]] > 1;
        (keep ? kept : free_faces).push_back(f);
    }
    const std::vector<int32_t> order =
        morton_order((int32_t)free_faces.size(), [&](int32_t i) { return first_point(free_faces[(size_t)i]); });
    for (int32_t i : order) kept.push_back(free_faces[(size_t)i]);
    return kept;
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

// The part of the mesh made of the faces in_part (all when in_part is
// empty).  Vertices the refiner sharpens after 3.6.0 (make_refiner) are
// sharpened in p as well, so that the sub-meshes of step 7 see them.
//    The sub-meshes of step 7 (`own` false) take p's sharpness as it is.
spia_result make_part(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                      const std::vector<char> &in_part, bool own, const unsigned char *one_fan, Part &part,
                      spia_status *status) {
    std::vector<int32_t> sharpened;
    const std::vector<int32_t> order = part_face_order(m, adj, in_part, one_fan);
    part.whole = in_part.empty() && order.empty();
    if (part.whole) {
        part.refiner.reset(make_refiner(p, opt, p.osd_n, m->face_count, m->face_sizes,
                                        p.remapped.empty() ? m->face_vertices : p.remapped.data(), p.crease_pairs,
                                        p.crease_weights, p.corner_indices, p.corner_weights, nullptr));
    } else {
        part.local_of.assign((size_t)p.osd_n, -1);
        const int32_t listed = order.empty() ? m->face_count : (int32_t)order.size();
        for (int32_t i = 0; i < listed; ++i) {
            const int32_t f = order.empty() ? i : order[(size_t)i];
            if (order.empty() && !in_part[f]) continue;
            part.mesh_face_of.push_back(f);
            part.sizes.push_back(m->face_sizes[f]);
            for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c) {
                const int32_t o = p.osd_of[m->face_vertices[c]];
                if (part.local_of[o] < 0) {
                    part.local_of[o] = (int32_t)part.osd_of_local.size();
                    part.osd_of_local.push_back(o);
                }
                part.fv.push_back(part.local_of[o]);
            }
        }
        restrict_sharpness(m, adj, p, part.local_of, in_part.empty() ? std::vector<char>((size_t)m->face_count, 1) : in_part,
                           part.crease_pairs, part.crease_weights, part.corner_indices, part.corner_weights);
        const int32_t count = (int32_t)part.osd_of_local.size(), faces = (int32_t)part.sizes.size();
        if (own)
            part.refiner.reset(make_refiner(p, opt, count, faces, part.sizes.data(), part.fv.data(), part.crease_pairs,
                                            part.crease_weights, part.corner_indices, part.corner_weights,
                                            &sharpened));
        else
            part.refiner.reset(create_refiner(count, faces, part.sizes.data(), part.fv.data(), part.crease_pairs,
                                              part.crease_weights, part.corner_indices, part.corner_weights, p.scheme,
                                              p.sdc));
        if (!sharpened.empty()) {
            std::vector<int32_t> corner_of((size_t)p.osd_n, -1);
            for (size_t k = 0; k < p.corner_indices.size(); ++k) corner_of[(size_t)p.corner_indices[k]] = (int32_t)k;
            for (int32_t i : sharpened) {
                const int32_t o = part.osd_of_local[(size_t)i];
                if (corner_of[(size_t)o] >= 0) {
                    p.corner_weights[(size_t)corner_of[(size_t)o]] = kInfiniteSharpness;
                } else {
                    p.corner_indices.push_back(o);
                    p.corner_weights.push_back(kInfiniteSharpness);
                }
            }
        }
    }
    if (!part.refiner) return spia__fail(status, SPIA_ERROR_TOPOLOGY, -1, "OpenSubdiv rejected the mesh topology");
    return SPIA_OK;
}

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

// The osd vertices of `list` in the order of the part's numbering (which
// follows its faces, part_face_order): walking the part's refiner in that
// order keeps its memory near.  For the loops whose results do not depend
// on the order.
std::vector<int32_t> in_part_order(const Part &part, const std::vector<int32_t> &list) {
    std::vector<int32_t> sorted(list);
    if (!part.whole)
        std::sort(sorted.begin(), sorted.end(), [&](int32_t a, int32_t b) { return part.vertex(a) < part.vertex(b); });
    return sorted;
}

// 6b. Semi-sharp vertices (their own sharpness or their edges') of manifold
//     fans, darts excepted.  Blender's patch corner there is the limit mask
//     of the vertex at level min(depth, quality), depth = ceil(its
//     sharpest semi-sharp feature), with whatever semi-sharpness is left at
//     that level taken as smooth (infinitely sharp edges stay sharp): where
//     the features have decayed within the isolation level this is the
//     exact limit point; where they have not, it is what the patches at the
//     isolation level give (tests/c/test_reference.cpp holds both to 1e-12
//     against the full adaptive table, at qualities 1 to 10).  A vertex's
//     one ring at the next level (itself, its edges' midpoints, its faces'
//     centres) depends on its one ring alone, and so does the sharpness of
//     its edges there: the row is the limit mask carried back through the
//     ring-to-ring steps, each step's masks from OpenSubdiv's own rules
//     (Sdc), with no mesh refined.  O(levels x valence) per vertex.  The
//     ring is read from the mesh where the closed rows found one
//     consistently oriented fan (6a, fan_ring_rows), which is every
//     manifold fan OpenSubdiv takes; those vertices need no refiner.

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

// Sdc's neighbourhood and mask interfaces over a ring's sharpness.
struct RingVertex {
    int n_edges, n_faces;
    float vertex_sharpness;
    const float *edge_sharpness;
    int GetNumEdges() const { return n_edges; }
    int GetNumFaces() const { return n_faces; }
    float GetSharpness() const { return vertex_sharpness; }
    float *GetSharpnessPerEdge(float *out) const {
        std::copy(edge_sharpness, edge_sharpness + n_edges, out);
        return out;
    }
    float GetChildSharpness(const Sdc::Crease &crease) const { return crease.SubdivideVertexSharpness(vertex_sharpness); }
    float *GetChildSharpnessPerEdge(const Sdc::Crease &crease, float *out) const {
        crease.SubdivideEdgeSharpnessesAroundVertex(n_edges, edge_sharpness, out);
        return out;
    }
};

struct RingEdge {  // as Vtr's EdgeInterface
    int n_faces;
    float sharpness;
    const int *face_sizes;
    int GetNumFaces() const { return n_faces; }
    float GetSharpness() const { return sharpness; }
    void GetChildSharpnesses(const Sdc::Crease &, float s[2]) const { s[0] = s[1] = sharpness - 1.0f; }
    void GetNumVerticesPerFace(int *sizes) const { std::copy(face_sizes, face_sizes + n_faces, sizes); }
};

struct RingMask {
    typedef double Weight;
    double *v, *e, *f;
    int nv = 0, ne = 0, nf = 0;
    bool centres = false;
    RingMask(double *vw, double *ew, double *fw) : v(vw), e(ew), f(fw) {}
    int GetNumVertexWeights() const { return nv; }
    int GetNumEdgeWeights() const { return ne; }
    int GetNumFaceWeights() const { return nf; }
    void SetNumVertexWeights(int c) { nv = c; }
    void SetNumEdgeWeights(int c) { ne = c; }
    void SetNumFaceWeights(int c) { nf = c; }
    const double &VertexWeight(int i) const { return v[i]; }
    const double &EdgeWeight(int i) const { return e[i]; }
    const double &FaceWeight(int i) const { return f[i]; }
    double &VertexWeight(int i) { return v[i]; }
    double &EdgeWeight(int i) { return e[i]; }
    double &FaceWeight(int i) { return f[i]; }
    bool AreFaceWeightsForFaceCenters() const { return centres; }
    void SetFaceWeightsForFaceCenters(bool on) { centres = on; }
};

struct RingScratch {
    std::vector<float> sharpness, child;
    std::vector<double> vertex_masks, edge_masks, g, next, centre_of_face;
};

// The row of the ring's centre at `levels` levels, over the mesh's
// vertices; false where a mask is not of the kind expected.
bool ring_row(const spia_mesh *m, const spia_adjacency *adj, const Ring &ring, float vertex_sharpness, int levels,
              const Sdc::Options &sdc, RingScratch &s, std::vector<Entry> &row) {
    auto face_size = [&](int32_t f) { return (int)(adj->corner_start[f + 1] - adj->corner_start[f]); };
    const Sdc::Scheme<Sdc::SCHEME_CATMARK> scheme(sdc);
    const Sdc::Crease crease(sdc);
    const int n = (int)ring.far_end.size(), nf = (int)ring.a.size();
    const size_t vm = 1 + (size_t)n + (size_t)nf, em = 4;  // a vertex mask; an edge mask (2 ends, 2 faces)
    s.sharpness.assign(ring.sharpness.begin(), ring.sharpness.end());
    s.vertex_masks.assign(vm * (size_t)levels, 0.0);
    s.edge_masks.assign(em * (size_t)n * (size_t)levels, 0.0);
    std::vector<float> &es = s.sharpness, &child = s.child;
    child.resize((size_t)n);
    int sizes[2];
    float vs = vertex_sharpness;
    for (int level = 0; level < levels; ++level) {
        double *w = s.vertex_masks.data() + vm * (size_t)level;
        RingVertex vertex{n, nf, vs, es.data()};
        RingMask mask(w, w + 1, w + 1 + n);
        crease.SubdivideEdgeSharpnessesAroundVertex(n, es.data(), child.data());
        const float child_vs = crease.SubdivideVertexSharpness(vs);
        const Sdc::Crease::Rule parent_rule = crease.DetermineVertexVertexRule(vs, n, es.data());
        const Sdc::Crease::Rule child_rule = crease.DetermineVertexVertexRule(child_vs, n, child.data());
        scheme.ComputeVertexVertexMask(vertex, mask, parent_rule, child_rule);
        if (mask.nv != 1 || (mask.ne != 0 && mask.ne != n) || (mask.nf != 0 && (mask.nf != nf || !mask.centres)))
            return false;
        if (mask.ne == 0) std::fill(w + 1, w + 1 + n, 0.0);
        if (mask.nf == 0) std::fill(w + 1 + n, w + vm, 0.0);
        for (int i = 0; i < n; ++i) {
            double *ew = s.edge_masks.data() + em * ((size_t)level * n + i);
            const int faces = ring.edge_face[2 * (size_t)i + 1] >= 0 ? 2 : 1;
            for (int k = 0; k < faces; ++k)
                sizes[k] = level == 0 ? face_size(ring.faces[(size_t)ring.edge_face[2 * (size_t)i + k]]) : 4;
            RingEdge edge{faces, es[(size_t)i], sizes};
            RingMask emask(ew, nullptr, ew + 2);
            const Sdc::Crease::Rule ep = es[(size_t)i] > 0.0f ? Sdc::Crease::RULE_CREASE : Sdc::Crease::RULE_SMOOTH;
            const Sdc::Crease::Rule ec = child[(size_t)i] > 0.0f ? Sdc::Crease::RULE_CREASE : Sdc::Crease::RULE_SMOOTH;
            scheme.ComputeEdgeVertexMask(edge, emask, ep, ec);
            if (emask.nv != 2 || emask.ne != 0 || (emask.nf != 0 && (emask.nf != faces || !emask.centres)))
                return false;
            if (emask.nf == 0) ew[2] = ew[3] = 0.0;
        }
        es.swap(child);
        vs = child_vs;
    }
    // The limit mask at the last level, semi-sharpness left taken as
    // smooth: weights on the centre, the far ends of its edges and the far
    // corners of its faces (quads there).
    s.g.assign(vm, 0.0);
    {
        for (float &x : es)
            if (x < kInfiniteSharpness) x = 0.0f;
        if (vs < kInfiniteSharpness) vs = 0.0f;
        RingVertex vertex{n, nf, vs, es.data()};
        RingMask mask(s.g.data(), s.g.data() + 1, s.g.data() + 1 + n);
        const Sdc::Crease::Rule rule = crease.DetermineVertexVertexRule(vs, n, es.data());
        if (rule == Sdc::Crease::RULE_DART || levels == 0) return false;
        scheme.ComputeVertexLimitMask(vertex, mask, rule);
        if (mask.nv != 1 || (mask.ne != 0 && mask.ne != n) || (mask.nf != 0 && (mask.nf != nf || mask.centres)))
            return false;
        if (mask.ne == 0) std::fill(s.g.begin() + 1, s.g.begin() + 1 + n, 0.0);
        if (mask.nf == 0) std::fill(s.g.begin() + 1 + n, s.g.end(), 0.0);
    }
    // Carried back level by level: g holds the weights on the level's
    // ring (centre, edge ends, far corners), centre_of_face those on the
    // centres of its faces, the next level's far corners.
    std::vector<double> &g = s.g, &next = s.next, &centre_of_face = s.centre_of_face;
    centre_of_face.resize((size_t)nf);
    for (int level = levels - 1; level >= 0; --level) {
        const double *w = s.vertex_masks.data() + vm * (size_t)level;
        const double gc = g[0];
        for (int j = 0; j < nf; ++j) centre_of_face[(size_t)j] = g[1 + (size_t)n + j] + w[1 + n + j] * gc;
        next.assign(vm, 0.0);
        next[0] = w[0] * gc;
        for (int i = 0; i < n; ++i) {
            const double *ew = s.edge_masks.data() + em * ((size_t)level * n + i);
            const double ge = g[1 + (size_t)i];
            next[0] += ew[0] * ge;
            next[1 + (size_t)i] = w[1 + i] * gc + ew[1] * ge;
            for (int k = 0; k < 2; ++k) {
                const int32_t j = ring.edge_face[2 * (size_t)i + k];
                if (j >= 0) centre_of_face[(size_t)j] += ew[2 + k] * ge;
            }
        }
        if (level > 0) {  // a face's centre is the mean of its four corners
            for (int j = 0; j < nf; ++j) {
                const double q = 0.25 * centre_of_face[(size_t)j];
                next[0] += q;
                next[1 + (size_t)ring.a[(size_t)j]] += q;
                next[1 + (size_t)ring.b[(size_t)j]] += q;
                next[1 + (size_t)n + j] = q;
            }
            g.swap(next);
            continue;
        }
        row.clear();
        row.emplace_back(ring.centre, next[0]);
        for (int i = 0; i < n; ++i) row.emplace_back(ring.far_end[(size_t)i], next[1 + (size_t)i]);
        for (int j = 0; j < nf; ++j) {  // the base level's faces, of any size
            const int32_t f = ring.faces[(size_t)j];
            const double q = centre_of_face[(size_t)j] * (1.0 / (double)face_size(f));
            for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c) row.emplace_back(m->face_vertices[c], q);
        }
    }
    merge_entries(row, true);
    return true;
}

// 6c. Non-manifold vertices.  Far makes every one infinitely sharp but a
//     vertex on a non-manifold crease (two non-manifold edges, no boundary,
//     more faces than edges; see on_nonmanifold_crease).  Blender's patch
//     corner is built from the span of faces, joined across manifold edges,
//     around the vertex's first face, between two singular edges; it is
//     sharp when the vertex is.  An infinitely sharp vertex stays where it
//     is at every level and is its own patch corner: the identity.  On a
//     crease (where no other edge is infinitely sharp), the vertex's points
//     at the next level (itself and its two non-manifold edges' midpoints)
//     depend on those three alone, with Sdc's corner, crease and
//     transitional masks while semi-sharp features decay; the span is
//     bounded by the two edges, or twice by one of them (a fin hanging from
//     it), and the patch corner is the boundary limit mask over the span's
//     ends at the isolation level, semi-sharpness left there taken as
//     smooth, as for the rings of step 6b.  Where the ends are the two
//     edges, that mask is the crease's own limit mask, and the same at
//     every level once the features have decayed.

// The edges that bound the span around v's first face: ends[0] reached
// from its edge leaving v, ends[1] from its edge arriving; false where a
// walk meets an edge with other than two faces or never ends.
bool span_ends(const Far::TopologyLevel &base, Far::Index v, Far::Index ends[2]) {
    Far::ConstIndexArray vf = base.GetVertexFaces(v);
    Far::ConstLocalIndexArray where = base.GetVertexFaceLocalIndices(v);
    int first = 0;
    for (int j = 1; j < vf.size(); ++j)
        if (vf[j] < vf[first]) first = j;
    Far::ConstIndexArray fe = base.GetFaceEdges(vf[first]);
    const int k = fe.size(), c = where[first];
    const Far::Index start[2] = {fe[c], fe[(c + k - 1) % k]};
    for (int side = 0; side < 2; ++side) {
        Far::Index e = start[side], f = vf[first];
        for (int steps = 0; !base.IsEdgeNonManifold(e); ++steps) {
            Far::ConstIndexArray ef = base.GetEdgeFaces(e);
            if (steps > vf.size() || ef.size() != 2) return false;
            f = ef[0] == f ? ef[1] : ef[0];
            Far::ConstIndexArray ge = base.GetFaceEdges(f), gv = base.GetFaceVertices(f);
            const int n = ge.size();
            int j = 0;
            while (j < n && ge[j] != e) ++j;
            if (j == n) return false;
            e = gv[j] == v ? ge[(j + n - 1) % n] : ge[(j + 1) % n];  // f's other edge at v
        }
        ends[side] = e;
    }
    return true;
}

// Whether step 6c takes v (Catmull-Clark as Blender sets it up), and how
// many levels deep: none for an infinitely sharp vertex, `depth` (at most
// the isolation level) for a span between the two edges, the isolation
// level for a span ending twice at one.
bool nonmanifold_levels(const Far::TopologyLevel &base, Far::Index v, int depth, int quality, int &levels) {
    levels = 0;
    if (base.GetVertexSharpness(v) >= kInfiniteSharpness) return true;
    Far::ConstIndexArray ve = base.GetVertexEdges(v);
    int crease = 0;
    for (int i = 0; i < ve.size(); ++i) {
        if (base.IsEdgeNonManifold(ve[i])) ++crease;
        else if (base.GetEdgeFaces(ve[i]).size() != 2 || base.GetEdgeSharpness(ve[i]) >= kInfiniteSharpness)
            return false;
    }
    Far::Index ends[2];
    if (crease != 2 || !span_ends(base, v, ends)) return false;
    levels = ends[0] != ends[1] ? std::min(depth, quality) : quality;
    return true;
}

bool nonmanifold_row(const Far::TopologyLevel &base, Far::Index v, int levels, const Sdc::Options &sdc,
                     RingScratch &s, std::vector<Entry> &row) {
    row.clear();
    float vs = base.GetVertexSharpness(v);
    if (vs >= kInfiniteSharpness) {
        row.emplace_back(v, 1.0);
        return true;
    }
    const Sdc::Scheme<Sdc::SCHEME_CATMARK> scheme(sdc);
    const Sdc::Crease crease(sdc);
    Far::ConstIndexArray ve = base.GetVertexEdges(v);
    const int n = ve.size(), nf = base.GetVertexFaces(v).size();
    int side[2] = {-1, -1};  // the two non-manifold edges' positions in ve
    Far::Index far_end[2] = {-1, -1};
    s.sharpness.resize((size_t)n);
    s.child.resize((size_t)n);
    for (int i = 0; i < n; ++i) {
        s.sharpness[(size_t)i] = base.GetEdgeSharpness(ve[i]);
        if (!base.IsEdgeNonManifold(ve[i])) continue;
        if (side[1] >= 0 || s.sharpness[(size_t)i] < kInfiniteSharpness) return false;
        const int k = side[0] >= 0;
        side[k] = i;
        Far::ConstIndexArray ends = base.GetEdgeVertices(ve[i]);
        far_end[k] = ends[0] == v ? ends[1] : ends[0];
    }
    Far::Index ends[2];
    if (side[1] < 0 || !span_ends(base, v, ends)) return false;
    // Level points (the vertex, then its neighbours along the two edges)
    // as weights on the base level's three.
    double point[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, next[3][3];
    s.vertex_masks.resize(1 + (size_t)n + (size_t)nf);
    double *w = s.vertex_masks.data();
    std::vector<float> &es = s.sharpness, &child = s.child;
    for (int level = 0; level < levels; ++level) {
        RingVertex vertex{n, nf, vs, es.data()};
        RingMask mask(w, w + 1, w + 1 + n);
        crease.SubdivideEdgeSharpnessesAroundVertex(n, es.data(), child.data());
        const float child_vs = crease.SubdivideVertexSharpness(vs);
        scheme.ComputeVertexVertexMask(vertex, mask, crease.DetermineVertexVertexRule(vs, n, es.data()),
                                       crease.DetermineVertexVertexRule(child_vs, n, child.data()));
        // The vertex's mask weighs only itself and the two edges' ends.
        if (mask.nv != 1 || mask.nf != 0 || (mask.ne != 0 && mask.ne != n)) return false;
        double m3[3] = {w[0], 0.0, 0.0};
        for (int i = 0; i < mask.ne; ++i) {
            if (i == side[0]) m3[1] = w[1 + i];
            else if (i == side[1]) m3[2] = w[1 + i];
            else if (w[1 + i] != 0.0) return false;
        }
        for (int c = 0; c < 3; ++c) {
            next[0][c] = m3[0] * point[0][c] + m3[1] * point[1][c] + m3[2] * point[2][c];
            for (int k = 1; k < 3; ++k) next[k][c] = 0.5 * (point[0][c] + point[k][c]);  // sharp edges' midpoints
        }
        std::memcpy(point, next, sizeof point);
        es.swap(child);
        vs = child_vs;
    }
    // The boundary limit mask over the span: 4/6 on the vertex, 1/6 on
    // each end's point.
    double limit[3] = {4.0 / 6.0, 0.0, 0.0};
    for (Far::Index e : ends) limit[e == ve[side[0]] ? 1 : 2] += 1.0 / 6.0;
    const Far::Index column[3] = {v, far_end[0], far_end[1]};
    for (int c = 0; c < 3; ++c)
        row.emplace_back(column[c], limit[0] * point[0][c] + limit[1] * point[1][c] + limit[2] * point[2][c]);
    merge_entries(row, true);
    return true;
}

// Whether a vertex of one of the faces around vertex v has more than 12
// faces.
bool next_to_high_valence(const Far::TopologyLevel &base, Far::Index v) {
    Far::ConstIndexArray vf = base.GetVertexFaces(v);
    for (int k = 0; k < vf.size(); ++k) {
        Far::ConstIndexArray fv = base.GetFaceVertices(vf[k]);
        for (int j = 0; j < fv.size(); ++j)
            if (base.GetVertexFaces(fv[j]).size() > 12) return true;
    }
    return false;
}

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
                       const Part &part, const std::vector<int32_t> &wanted, Evaluation &ev) {
    const Far::TopologyLevel &base = part.refiner->GetLevel(0);
    const bool blender = p.blender;
    auto non_manifold = [&](int32_t o) { return base.IsVertexNonManifold(part.vertex(o)); };
    // The corner at which Bfr evaluates a smooth vertex: its corner of its
    // first face, or of the first face with no non-manifold vertex, since
    // Bfr's irregular patch builder in OpenSubdiv 3.5 writes out of bounds on
    // some faces next to non-manifold vertices (seen on the Stanford dragon
    // scan).  The limit point of a smooth vertex is the same from every face.
    auto clean_face = [&](int32_t f) {
        for (int64_t d = adj->corner_start[f]; d < adj->corner_start[f + 1]; ++d)
            if (non_manifold(p.osd_of[m->face_vertices[d]])) return false;
        return true;
    };
    ev.adaptive.assign((size_t)p.osd_n, 0);
    ev.bfr_corner.assign((size_t)p.osd_n, -1);
    std::vector<char> approx((size_t)p.osd_n, 0);
    bool any_approx = false;
    for (int32_t o : in_part_order(part, wanted)) {
        const int32_t lo = part.vertex(o);
        const float vs = base.GetVertexSharpness(lo);
        Far::ConstIndexArray ve = base.GetVertexEdges(lo);
        // Infinitely sharp interior edges (non-manifold edges are, in Far).
        int infinitely_sharp = 0;
        bool semi_sharp = vs > 0.0f && vs < kInfiniteSharpness;
        float sharpest = semi_sharp ? vs : 0.0f;  // of the semi-sharp features
        for (int k = 0; k < ve.size(); ++k) {
            Far::Index e = ve[k];
            if (base.GetEdgeFaces(e).size() == 1 && !base.IsEdgeNonManifold(e)) continue;  // boundary
            const float es = base.GetEdgeSharpness(e);
            if (es >= kInfiniteSharpness || base.IsEdgeNonManifold(e)) {
                ++infinitely_sharp;
            } else if (es > 0.0f) {
                semi_sharp = true;
                sharpest = std::max(sharpest, es);
            }
        }
        // Darts (one infinitely sharp edge at a manifold vertex) and
        // non-manifold vertices: Blender's patches there do not reproduce
        // the closed-form corner or crease masks (measured on the dragon
        // scan, up to 1.3e-4 of the diagonal at vertices with 7 to 12
        // faces); most non-manifold ones have rows of their own (step 6c).
        // Darts and semi-sharp vertices take Bfr at the isolation level
        // (Catmull-Clark only: Loop is taken at its exact limit).
        const bool dart = infinitely_sharp == 1;
        const bool smooth_corner = blender && opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_ALL &&
                                   base.IsVertexBoundary(lo) && ve.size() == 2;
        bool adaptive = smooth_corner;  // Blender is not at the limit there
        // Where step 7 takes it, the level that gives Blender's patch
        // corner: the isolation level where that depends on it (smooth
        // corners, darts, non-manifold vertices), else the level by which
        // the semi-sharp features have decayed (and at least 1), from
        // which on the vertex is smooth and its patch corner is its limit
        // point at any level; next to non-manifold vertices, which are
        // isolated as deep as asked, ten levels cost seconds.
        const int depth = (int)std::ceil(sharpest);
        const bool at_quality = !blender || smooth_corner || dart || base.IsVertexNonManifold(lo);
        const int adaptive_level = at_quality ? opt->quality : std::max(1, std::min(depth, opt->quality));
        if (!adaptive && base.IsVertexNonManifold(lo)) {
            // Infinitely sharp ones and those on a non-manifold crease
            // from the crease (step 6c); the others adaptive.
            int levels = 0;
            if (blender && nonmanifold_levels(base, lo, depth, opt->quality, levels)) {
                ev.ring.push_back(o);
                ev.levels.push_back(levels);
                continue;
            }
            adaptive = true;
        }
        if (!adaptive && (semi_sharp || dart)) {
            // (Semi-sharp vertices of a fan that is no dart have their rows
            // from their ring already, 6a.)  Bfr is the faster of the two where the faces around are of
            // low valence; next to a vertex of high valence its irregular
            // patches cost more than Far's adaptive ones (measured on the
            // hard set: a sphere with poles of valence 400, a printer bed).
            if (blender && !next_to_high_valence(base, lo)) approx[o] = 1;
            else adaptive = true;
        }
        if (!adaptive) {
            const int32_t v = p.vertex_of[o];
            for (int64_t i = adj->first[v]; i < adj->first[v + 1] && ev.bfr_corner[o] < 0; ++i) {
                int64_t c = adj->corner_of[i];
                if (clean_face(adj->face_of_corner[c])) ev.bfr_corner[o] = (int32_t)c;
            }
            adaptive = ev.bfr_corner[o] < 0;
        }
        if (adaptive) {
            approx[o] = 0;
            ev.adaptive[o] = (char)adaptive_level;
            ++ev.adaptive_count;
        }
        any_approx = any_approx || approx[o];
    }
    if (!any_approx) return;
    // 6. Vertices with a closed form come out the same from any of their
    //    faces and at any level: where one of their clean faces already
    //    gives a vertex at the isolation level, they share its surface
    //    instead of costing one more (a sharp face at Bfr's default levels is
    //    the dearest of all).  The same holds for the vertices taken at the
    //    isolation level (Blender evaluates them on their first face; their
    //    limit point is the corner their patches share, which
    //    test_reference checks with the last face as well): each takes a
    //    clean face that already gives one, else the clean face with the
    //    most such vertices, so that fewer irregular surfaces are built.
    ev.level_face.assign((size_t)m->face_count, 0);
    for (int32_t o : wanted) {
        if (!approx[o]) continue;
        const int32_t v = p.vertex_of[o];
        int64_t best = -1;
        int best_count = -1;
        for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
            const int64_t c = adj->corner_of[i];
            const int32_t f = adj->face_of_corner[c];
            if (!clean_face(f)) continue;
            int count = 0;
            if (ev.level_face[f]) {
                count = INT32_MAX;
            } else {
                for (int64_t d = adj->corner_start[f]; d < adj->corner_start[f + 1]; ++d)
                    count += approx[p.osd_of[m->face_vertices[d]]];
            }
            if (count > best_count) {
                best_count = count;
                best = c;
            }
        }
        ev.bfr_corner[o] = (int32_t)best;  // the loop above found a clean face, so best >= 0
        ev.level_face[adj->face_of_corner[best]] = 1;
    }
    for (int32_t o : wanted) {
        if (approx[o] || ev.bfr_corner[o] < 0 || ev.level_face[adj->face_of_corner[ev.bfr_corner[o]]]) continue;
        const int32_t v = p.vertex_of[o];
        for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
            const int64_t c = adj->corner_of[i];
            const int32_t f = adj->face_of_corner[c];
            if (ev.level_face[f] && clean_face(f)) {
                ev.bfr_corner[o] = (int32_t)c;
                break;
            }
        }
    }
}

// Orders osd vertices along a Morton curve through their positions (ties
// by index), so that batches of consecutive ones are close together and
// share their sub-meshes whatever the mesh's vertex order.
void spatial_order(const spia_mesh *m, const Prepared &p, std::vector<int32_t> &list) {
    const std::vector<int32_t> order = morton_order((int32_t)list.size(), [&](int32_t i) {
        return m->positions + 3 * (int64_t)p.vertex_of[(size_t)list[(size_t)i]];
    });
    std::vector<int32_t> sorted(list.size());
    for (size_t i = 0; i < list.size(); ++i) sorted[i] = list[(size_t)order[i]];
    list.swap(sorted);
}


// 6c, on the threads: each non-manifold vertex's row from its crease.
spia_result ring_rows(const spia_options *opt, const Prepared &p, const Part &part, const Evaluation &ev,
                      HeldRows &held, spia_status *status) {
    const int32_t count = (int32_t)ev.ring.size();
    if (count == 0) return SPIA_OK;
    const Far::TopologyLevel &base = part.refiner->GetLevel(0);
    const int32_t batch = 1024, batches = (count + batch - 1) / batch;
    std::vector<std::vector<Entry>> rows((size_t)count);
    std::vector<int32_t> at((size_t)count);  // the ring vertices by their place in the part
    for (int32_t i = 0; i < count; ++i) at[(size_t)i] = i;
    if (!part.whole)
        std::sort(at.begin(), at.end(),
                  [&](int32_t a, int32_t b) { return part.vertex(ev.ring[(size_t)a]) < part.vertex(ev.ring[(size_t)b]); });
    std::atomic<bool> failed(false);
    run_batches(opt->threads, batches, [&](int32_t b) {
        RingScratch scratch;
        for (int32_t j = b * batch; j < std::min(count, (b + 1) * batch); ++j) {
            const int32_t i = at[(size_t)j];
            const int32_t lo = part.vertex(ev.ring[(size_t)i]);
            std::vector<Entry> &row = rows[(size_t)i];
            if (!base.IsVertexNonManifold(lo) || !nonmanifold_row(base, lo, ev.levels[(size_t)i], p.sdc, scratch, row))
                failed = true;
            for (Entry &e : row) e.first = part.osd(e.first);
        }
    }, [&](int32_t) { failed = true; });
    if (failed) return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "a sharp feature's ring masks failed");
    for (int32_t i = 0; i < count; ++i) held.hold(p, ev.ring[(size_t)i], rows[(size_t)i]);
    return SPIA_OK;
}

// 7. The vertices marked adaptive: Blender's adaptive patches at quality,
//    one limit location per vertex: its corner of its first face.  Patches
//    are built for every face of a refiner, so each refiner holds only the
//    faces within two rings of its vertices (two_ring_faces), with the whole
//    mesh's sharpness.  The vertices are taken in batches of consecutive
//    vertices, each with its own sub-mesh, so that OpenSubdiv's tables
//    (which hold every refined vertex) stay small, and batches run on the
//    threads.  The batches (consecutive along a Morton curve, spatial_order)
//    do not depend on the thread count.  Each batch holds vertices of one
//    level (ev.adaptive: the isolation level, or less where the patch
//    corner is the same from a lower one, step 5).
struct FeatureBatch {
    int32_t first, count, level;  // features[first .. first + count - 1], all of one level
};

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

// The adaptive vertices by level, spatially ordered within one, and their
// batches.
void feature_batches(const spia_mesh *m, const Prepared &p, const Evaluation &ev, std::vector<int32_t> &features,
                     std::vector<FeatureBatch> &batch_list) {
    const int32_t feature_count = ev.adaptive_count;
    // (a level's last batch may be short: at most one more sub-mesh per level)
    const int32_t batch_size =
        std::max<int32_t>(kFeatureBatch, (feature_count + kMaxFeatureBatches - 1) / kMaxFeatureBatches);
    features.reserve((size_t)feature_count);
    for (int32_t o = 0; o < p.osd_n; ++o)
        if (ev.adaptive[o]) features.push_back(o);
    spatial_order(m, p, features);
    std::stable_sort(features.begin(), features.end(),
                     [&](int32_t a, int32_t b) { return ev.adaptive[a] < ev.adaptive[b]; });
    for (int32_t i = 0; i < feature_count;) {
        const int level = ev.adaptive[features[(size_t)i]];
        int32_t end = i;
        while (end < feature_count && end - i < batch_size && ev.adaptive[features[(size_t)end]] == level) ++end;
        batch_list.push_back(FeatureBatch{i, end - i, level});
        i = end;
    }
}

// Loop is taken at its exact limit: each vertex refined on its own fan
// until its semi-sharp features have decayed, then OpenSubdiv's limit
// masks (fan_limit_rows), on sparse stencils.
void loop_batch_rows(const Part &sub, const std::vector<int32_t> &marked, const Prepared &p, BatchRows &out) {
    const int32_t sub_n = (int32_t)sub.osd_of_local.size();
    bool bad_column = false;
    auto add_row = [&](int32_t o, const SparseStencil &st) {
        out.begin_row(o);
        for (const auto &e : st.w) {
            if (e.first < 0 || e.first >= sub_n) {
                bad_column = true;
                continue;
            }
            out.add(sub.osd_of_local[(size_t)e.first], e.second);
        }
    };
    if (!fan_limit_rows(*sub.refiner, marked, sub.local_of, p.scheme, p.sdc, add_row) || bad_column)
        out.failed(SPIA_ERROR_INTERNAL, -1, "OpenSubdiv's limit masks failed", 0, 0);
    out.end();
}

// Each marked vertex's limit location: its corner of its first face, in
// the sub-mesh's ptex faces.
void corner_locations(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const Part &sub,
                      const std::vector<int32_t> &sub_face_of, const std::vector<int32_t> &marked,
                      LimitFactory::LocationArrayVec &locations) {
    // Corners of a quad ptex face.
    static const double corner_s[4] = {0.0, 1.0, 1.0, 0.0};
    static const double corner_t[4] = {0.0, 0.0, 1.0, 1.0};
    Far::PtexIndices ptex(*sub.refiner);
    locations.reserve(marked.size());
    for (int32_t o : marked) {
        const int32_t v = p.vertex_of[o];
        const int64_t c = adj->corner_of[adj->first[v]];
        const int32_t f = adj->face_of_corner[c];
        const int32_t k = (int32_t)(c - adj->corner_start[f]);
        LimitFactory::LocationArray loc;
        loc.numLocations = 1;
        if (m->face_sizes[f] == 4) {
            loc.ptexIdx = ptex.GetFaceId(sub_face_of[f]);
            loc.s = &corner_s[k];
            loc.t = &corner_t[k];
        } else {
            loc.ptexIdx = ptex.GetFaceId(sub_face_of[f]) + k;
            loc.s = &corner_s[0];
            loc.t = &corner_t[0];
        }
        locations.push_back(loc);
    }
}

// What LimitStencilTableFactory computes, with the same patch options, but
// without its stencil for every refined point (whose merging costs the
// square of its length, hundreds of weights around vertices of high
// valence): each level's points as stencils over the previous level's (a
// few weights each, steps[l]), level l's points numbered from
// level_start[l]; each vertex's row is carried down from its patch's
// points (patch_rows).
void level_steps(Far::TopologyRefiner &sr, std::vector<int64_t> &level_start,
                 std::vector<std::vector<SparseStencil>> &steps) {
    const int max_level = sr.GetMaxLevel();
    level_start.assign((size_t)max_level + 2, 0);
    for (int l = 0; l <= max_level; ++l)
        level_start[(size_t)l + 1] = level_start[(size_t)l] + sr.GetLevel(l).GetNumVertices();
    steps.resize((size_t)max_level + 1);
    Far::PrimvarRefinerReal<double> primvar(sr);
    std::vector<SparseStencil> identity;
    for (int l = 1; l <= max_level; ++l) {
        const int32_t prev = sr.GetLevel(l - 1).GetNumVertices();
        identity.resize((size_t)prev);
        for (int32_t i = 0; i < prev; ++i) identity[(size_t)i].w.assign(1, std::make_pair(i, 1.0));
        steps[(size_t)l].resize((size_t)sr.GetLevel(l).GetNumVertices());
        SparseStencil *src = identity.data(), *dst = steps[(size_t)l].data();
        primvar.Interpolate(l, src, dst);
        for (SparseStencil &st : steps[(size_t)l]) st.Compact();
    }
}

// The marked vertices' rows from the patches at their locations, carried
// down the levels to the sub-mesh's control vertices (osd numbering).
// false when a row fails (out's failure says why).
bool patch_rows(const Prepared &p, const Part &sub, const std::vector<int32_t> &marked,
                const LimitFactory::LocationArrayVec &locations, const Far::PatchTable &patches,
                const std::vector<int64_t> &level_start, const std::vector<std::vector<SparseStencil>> &steps,
                BatchRows &out) {
    const int32_t sub_n = (int32_t)sub.osd_of_local.size();
    const int max_level = (int)steps.size() - 1;
    const Far::StencilTableReal<double> *local = patches.GetLocalPointStencilTable<double>();
    Far::PatchMap patch_map(patches);
    const int64_t total = level_start[(size_t)max_level + 1];
    std::vector<std::pair<int64_t, double>> row, wider;  // global point index, weight
    double basis[64];
    for (size_t i = 0; i < marked.size(); ++i) {
        const int32_t o = marked[i];
        const LimitFactory::LocationArray &loc = locations[i];
        const Far::PatchTable::PatchHandle *handle = patch_map.FindPatch(loc.ptexIdx, loc.s[0], loc.t[0]);
        if (!handle) {
            out.failed(SPIA_ERROR_INTERNAL, p.vertex_of[o], "OpenSubdiv found no patch at vertex %d", p.vertex_of[o], 0);
            return false;
        }
        Far::ConstIndexArray cvs = patches.GetPatchVertices(*handle);
        if (cvs.size() > 64) {
            out.failed(SPIA_ERROR_INTERNAL, p.vertex_of[o], "a patch with %d points at vertex %d", cvs.size(),
                       p.vertex_of[o]);
            return false;
        }
        patches.EvaluateBasis(*handle, loc.s[0], loc.t[0], basis);
        row.clear();
        for (int k = 0; k < cvs.size(); ++k) {
            if (cvs[k] < total) {
                row.emplace_back(cvs[k], basis[k]);
            } else if (local) {
                const Far::StencilReal<double> st = local->GetStencil((Far::Index)(cvs[k] - total));
                for (int j = 0; j < st.GetSize(); ++j)
                    row.emplace_back(st.GetVertexIndices()[j], basis[k] * st.GetWeights()[j]);
            }
        }
        // Down the levels: points of level l in terms of level l - 1's.
        for (int l = max_level; l >= 1; --l)
            carry_down<int64_t>(row, steps[(size_t)l], level_start[(size_t)l], level_start[(size_t)l + 1],
                                level_start[(size_t)l - 1], wider);
        merge_entries(row, true);  // (already merged, unless no level was refined)
        out.begin_row(o);
        for (const auto &e : row) {
            if (e.first < 0 || e.first >= sub_n) {
                out.failed(SPIA_ERROR_INTERNAL, p.vertex_of[o],
                           "OpenSubdiv stencil refers to point %d, not a control vertex", (int)e.first, 0);
                return false;
            }
            out.add(sub.osd_of_local[(size_t)e.first], e.second);
        }
    }
    return true;
}

// One batch: its sub-mesh, refined adaptively around the faces its
// vertices are evaluated on (Catmull-Clark), and their rows.
void adaptive_batch(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                    const std::vector<int32_t> &marked, int level, BatchRows &out) {
    Part sub;
    spia_status local_status;
    if (make_part(m, adj, opt, p, two_ring_faces(m, adj, p, marked), false, nullptr, sub, &local_status) != SPIA_OK) {
        out.failed(SPIA_ERROR_TOPOLOGY, -1, "OpenSubdiv rejected the topology around sharp features", 0, 0);
        return;
    }
    std::vector<int32_t> sub_face_of((size_t)m->face_count, -1);
    for (size_t i = 0; i < sub.mesh_face_of.size(); ++i) sub_face_of[(size_t)sub.mesh_face_of[i]] = (int32_t)i;
    if (!p.blender) {
        loop_batch_rows(sub, marked, p, out);
        return;
    }
    // Refined around the faces the vertices are evaluated on.
    std::vector<Far::Index> feature_faces;
    for (int32_t o : marked) {
        const int32_t v = p.vertex_of[o];
        feature_faces.push_back(sub_face_of[adj->face_of_corner[adj->corner_of[adj->first[v]]]]);
    }
    std::sort(feature_faces.begin(), feature_faces.end());
    feature_faces.erase(std::unique(feature_faces.begin(), feature_faces.end()), feature_faces.end());
    Far::TopologyRefiner::AdaptiveOptions adaptive(level);
    adaptive.useInfSharpPatch = true;
    adaptive.considerFVarChannels = false;
    sub.refiner->RefineAdaptive(adaptive, Far::ConstIndexArray(feature_faces.data(), (int)feature_faces.size()));

    LimitFactory::LocationArrayVec locations;
    corner_locations(m, adj, p, sub, sub_face_of, marked, locations);
    Far::TopologyRefiner &sr = *sub.refiner;
    std::vector<int64_t> level_start;
    std::vector<std::vector<SparseStencil>> steps;
    level_steps(sr, level_start, steps);
    Far::PatchTableFactory::Options patch_options;
    patch_options.SetPatchPrecision<double>();
    patch_options.includeBaseLevelIndices = true;
    patch_options.SetEndCapType(Far::PatchTableFactory::Options::ENDCAP_GREGORY_BASIS);
    patch_options.useInfSharpPatch = true;
    std::unique_ptr<Far::PatchTable> patches(Far::PatchTableFactory::Create(
        sr, patch_options, Far::ConstIndexArray(feature_faces.data(), (int)feature_faces.size())));
    if (!patches) {
        out.failed(SPIA_ERROR_INTERNAL, -1, "OpenSubdiv built no patches around %d vertices", (int)marked.size(), 0);
        return;
    }
    if (patch_rows(p, sub, marked, locations, *patches, level_start, steps, out)) out.end();
}

spia_result adaptive_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                          const Evaluation &ev, HeldRows &held, spia_status *status) {
    if (ev.adaptive_count == 0) return SPIA_OK;
    std::vector<int32_t> features;
    std::vector<FeatureBatch> batch_list;
    feature_batches(m, p, ev, features, batch_list);
    const int32_t batches = (int32_t)batch_list.size();
    std::vector<BatchRows> results((size_t)batches);
    run_batches(opt->threads, batches, [&](int32_t b) {
        const FeatureBatch &batch = batch_list[(size_t)b];
        const int32_t *first = features.data() + batch.first;
        const std::vector<int32_t> marked(first, first + batch.count);
        adaptive_batch(m, adj, opt, p, marked, batch.level, results[(size_t)b]);
    }, [&](int32_t b) {
        results[(size_t)b].code = SPIA_ERROR_INTERNAL;
        snprintf(results[(size_t)b].message, SPIA_MESSAGE_SIZE, "unexpected failure around sharp features");
    });
    for (BatchRows &out : results)
        if (out.code != SPIA_OK) return spia__fail(status, out.code, out.index, "%s", out.message);
    for (BatchRows &out : results) {
        std::vector<std::pair<int32_t, double>> row;
        for (size_t r = 0; r < out.vertex.size(); ++r) {
            row.clear();
            for (int64_t k = out.start[r]; k < out.start[r + 1]; ++k)
                row.emplace_back(out.indices[(size_t)k], out.weights[(size_t)k]);
            held.hold(p, out.vertex[r], row);
        }
        std::vector<int32_t>().swap(out.indices);
        std::vector<double>().swap(out.weights);
    }
    return SPIA_OK;
}

// The table under construction, written in place: each row gets room for a
// bound on its length, is filled, sorted, merged and stripped of zeros
// there, and the rows are then moved together (finish).  A row longer than
// its bound (not expected) is kept aside and the arrays are rebuilt to fit.
struct TableWriter {
    spia_stencils *s = nullptr;
    std::vector<int32_t> length;  // per row: its bound, then its length once written
    std::vector<std::pair<int32_t, std::vector<Entry>>> spilled;

    // Row v from entries in caller numbering (any order, repeats allowed):
    // stable sort by column, repeats added up in order, zeros dropped.
    void write(int32_t v, std::vector<Entry> &row, std::vector<std::pair<int32_t, std::vector<Entry>>> &spill) {
        for (size_t i = 1; i < row.size(); ++i) {
            Entry e = row[i];
            size_t j = i;
            while (j > 0 && row[j - 1].first > e.first) {
                row[j] = row[j - 1];
                --j;
            }
            row[j] = e;
        }
        size_t out = 0;
        for (size_t i = 0; i < row.size();) {
            const int32_t k = row[i].first;
            double w = 0.0;
            while (i < row.size() && row[i].first == k) w += row[i++].second;
            if (w != 0.0) row[out++] = Entry(k, w);
        }
        row.resize(out);
        length[(size_t)v] = (int32_t)out;
        if ((int64_t)out > s->offsets[v + 1] - s->offsets[v]) {
            spill.emplace_back(v, row);
            return;
        }
        for (size_t i = 0; i < out; ++i) {
            s->indices[s->offsets[v] + (int64_t)i] = row[i].first;
            s->weights[s->offsets[v] + (int64_t)i] = row[i].second;
        }
    }

    // 11. Rows moved together (or, if some were spilled, copied into arrays
    //     that fit them all).  Returns the finished table, or nullptr when
    //     out of memory (s is then still owned by the caller).
    spia_stencils *finish(int32_t n) {
        if (spilled.empty()) {
            int64_t pos = 0;
            for (int32_t v = 0; v < n; ++v) {
                const int64_t start = s->offsets[v];
                s->offsets[v] = pos;
                if (start != pos) {
                    memmove(s->indices + pos, s->indices + start, sizeof(int32_t) * (size_t)length[v]);
                    memmove(s->weights + pos, s->weights + start, sizeof(double) * (size_t)length[v]);
                }
                pos += length[v];
            }
            s->offsets[n] = pos;
            s->nnz = pos;
            spia__stencils_shrink(s);
            return s;
        }
        std::sort(spilled.begin(), spilled.end(),
                  [](const std::pair<int32_t, std::vector<Entry>> &a, const std::pair<int32_t, std::vector<Entry>> &b) {
                      return a.first < b.first;
                  });
        int64_t total = 0;
        for (int32_t v = 0; v < n; ++v) total += length[v];
        spia_stencils *t = spia__stencils_alloc(n, total);
        if (!t) return nullptr;
        size_t next = 0;
        int64_t pos = 0;
        for (int32_t v = 0; v < n; ++v) {
            t->offsets[v] = pos;
            if (next < spilled.size() && spilled[next].first == v) {
                for (const Entry &e : spilled[next].second) {
                    t->indices[pos] = e.first;
                    t->weights[pos++] = e.second;
                }
                ++next;
            } else {
                memcpy(t->indices + pos, s->indices + s->offsets[v], sizeof(int32_t) * (size_t)length[v]);
                memcpy(t->weights + pos, s->weights + s->offsets[v], sizeof(double) * (size_t)length[v]);
                pos += length[v];
            }
        }
        t->offsets[n] = pos;
        t->nnz = pos;
        spia_stencils_free(s);
        s = t;
        return t;
    }
};

// 10. Bfr at the corners chosen in step 5: at its default options, unless
//     the face also gives a vertex at the isolation level: then the face's
//     one surface at that level serves both (closed-form vertices come out
//     the same from Blender's patches at any level).  Faces are shared out
//     among threads; each row comes from one face, so the table is the same
//     whatever the number of threads.  Faces go in blocks of kFaceBlock,
//     each with factories of its own and so its own cache of irregular
//     patches (keyed by topology): a cache shared between threads measured
//     no faster with two threads than with one, its lock taken for every
//     face, and one cache per thread for the whole mesh grew to 1.6 kB a
//     vertex on the creased 1M-vertex sphere (0.85 kB per block, for about
//     the same time).
spia_result bfr_rows(const spia_mesh *m, const int64_t *corner_start, const spia_options *opt, const Prepared &p,
                     const Part &part, const Evaluation &ev, TableWriter &table, spia_status *status) {
    Bfr::SurfaceFactory::Options qopt;
    qopt.SetApproxLevelSharp(opt->quality).SetApproxLevelSmooth(opt->quality);
    const Far::TopologyRefiner &refiner = *part.refiner;
    const int32_t face_count = refiner.GetLevel(0).GetNumFaces();
    const int threads = opt->threads > 0 ? opt->threads : 1;
    std::vector<int32_t> failed_face_of((size_t)threads, INT32_MAX);  // per thread, the first face Bfr failed on
    std::vector<unsigned char> out_of_memory_of((size_t)threads, 0), other_failure_of((size_t)threads, 0);
    std::vector<std::vector<std::pair<int32_t, std::vector<Entry>>>> spill_of((size_t)threads);
    const int32_t blocks = (face_count + kFaceBlock - 1) / kFaceBlock;
    parallel_for(threads, blocks, 1, [&](int64_t fb0, int64_t fb1, int thread) {
        try {
            Bfr::Surface<double> srf;
            std::vector<Far::Index> cv;
            std::vector<double> w;
            std::vector<Entry> row;
            for (int32_t fb = (int32_t)fb0; fb < (int32_t)fb1; ++fb) {
                Bfr::RefinerSurfaceFactory<> factory(refiner, Bfr::SurfaceFactory::Options()),
                    qfactory(refiner, qopt);
                const int32_t i_end = (int32_t)std::min<int64_t>(face_count, (int64_t)(fb + 1) * kFaceBlock);
                for (int32_t i = fb * kFaceBlock; i < i_end; ++i) {
                    const int32_t f = part.mesh_face(i);
                    bool initialized = false;
                    const bool q = !ev.level_face.empty() && ev.level_face[f];
                    for (int64_t c = corner_start[f]; c < corner_start[f + 1]; ++c) {
                        const int32_t o = p.osd_of[m->face_vertices[c]];
                        if (ev.bfr_corner[o] != c) continue;
                        if (!initialized) {
                            if (!(q ? qfactory.InitVertexSurface(i, &srf) : factory.InitVertexSurface(i, &srf)) ||
                                !srf.IsValid()) {
                                failed_face_of[(size_t)thread] = std::min(failed_face_of[(size_t)thread], f);
                                break;
                            }
                            initialized = true;
                            cv.resize((size_t)srf.GetNumControlPoints());
                            w.resize(cv.size());
                            srf.GetControlPointIndices(cv.data());
                        }
                        double uv[2];
                        srf.GetParameterization().GetVertexCoord((int)(c - corner_start[f]), uv);
                        srf.EvaluateStencil(uv, w.data());
                        row.clear();
                        for (size_t k = 0; k < cv.size(); ++k)
                            if (w[k] != 0.0) row.emplace_back(p.vertex_of[part.osd(cv[k])], w[k]);
                        table.write(m->face_vertices[c], row, spill_of[(size_t)thread]);
                    }
                }
            }
        } catch (const std::bad_alloc &) {
            out_of_memory_of[(size_t)thread] = 1;
        } catch (...) {
            other_failure_of[(size_t)thread] = 1;
        }
    });
    int32_t failed_face = INT32_MAX;
    bool out_of_memory = false, other_failure = false;
    for (int t = 0; t < threads; ++t) {
        failed_face = std::min(failed_face, failed_face_of[(size_t)t]);
        out_of_memory = out_of_memory || out_of_memory_of[(size_t)t];
        other_failure = other_failure || other_failure_of[(size_t)t];
    }
    if (out_of_memory) throw std::bad_alloc();
    if (other_failure) return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing limit stencils");
    if (failed_face != INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INTERNAL, failed_face, "OpenSubdiv built no limit surface for face %d",
                          (int)failed_face);
    for (auto &part_spill : spill_of)
        for (auto &r : part_spill) table.spilled.push_back(std::move(r));
    return SPIA_OK;
}

// The sharpness of p as catmark_closed.c reads it.
spia_catmark_sharpness sharpness_view(const Prepared &p, const spia_options *opt) {
    spia_catmark_sharpness sh;
    sh.vertex = p.vertex_sharpness.data();
    sh.crease_first = p.crease_first.empty() ? nullptr : p.crease_first.data();
    sh.crease_other = p.crease_other.empty() ? nullptr : p.crease_other.data();
    sh.crease_sharpness = p.crease_sharpness.empty() ? nullptr : p.crease_sharpness.data();
    sh.preserve_corners = opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS;
    return sh;
}

// 6a. Semi-sharp vertices of one consistently oriented fan (the closed
//     rows found the fan: on_boundary 0 or 1), darts and smooth corners
//     excepted: the ring of 6b read from the mesh itself, with no refiner.
//     Its faces and edges go in the order Far's refiner of the mesh gives
//     them (Vtr orders them from the vertex's first face in the mesh, or on
//     the boundary from the face whose edge after the vertex is on the
//     boundary, each next face the one whose edge after the vertex is the
//     current face's edge before it), as Sdc adds up the edges' sharpness
//     in float in that order.  Returns the levels of 6b, or 0 where the
//     vertex is not such a vertex.
int fan_ring(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const spia_catmark_sharpness &sh,
             const spia_options *opt, int32_t v, bool boundary, std::vector<int32_t> &next, std::vector<int32_t> &prev,
             Ring &ring) {
    const int64_t first = adj->first[v];
    const int k = (int)(adj->first[v + 1] - first);
    if (k < (boundary ? 2 : 3)) return 0;  // smooth corners (adaptive), two faces (Bfr)
    next.resize((size_t)k);
    prev.resize((size_t)k);
    ring.faces.resize((size_t)k);
    for (int i = 0; i < k; ++i) {
        const int64_t c = adj->corner_of[first + i];
        ring.faces[(size_t)i] = adj->face_of_corner[c];
        next[(size_t)i] = spia__corner_next(m, adj, c);
        prev[(size_t)i] = spia__corner_prev(m, adj, c);
    }
    // The faces in Vtr's order, in place: face t + 1 is the one whose next
    // is face t's prev.
    int start = 0;
    if (boundary) {
        start = -1;
        for (int i = 0; i < k && start < 0; ++i) {
            bool led = false;
            for (int j = 0; j < k && !led; ++j) led = prev[(size_t)j] == next[(size_t)i];
            if (!led) start = i;
        }
        if (start < 0) return 0;
    }
    auto swap_faces = [&](int i, int j) {
        std::swap(ring.faces[(size_t)i], ring.faces[(size_t)j]);
        std::swap(next[(size_t)i], next[(size_t)j]);
        std::swap(prev[(size_t)i], prev[(size_t)j]);
    };
    swap_faces(0, start);
    for (int t = 1; t < k; ++t) {
        int found = -1;
        for (int j = t; j < k && found < 0; ++j)
            if (next[(size_t)j] == prev[(size_t)t - 1]) found = j;
        if (found < 0) return 0;
        swap_faces(t, found);
    }
    const int n = boundary ? k + 1 : k;
    ring.centre = v;
    ring.far_end.resize((size_t)n);
    ring.sharpness.resize((size_t)n);
    ring.a.resize((size_t)k);
    ring.b.resize((size_t)k);
    ring.edge_face.assign(2 * (size_t)n, -1);
    for (int t = 0; t < k; ++t) ring.far_end[(size_t)t] = next[(size_t)t];
    if (boundary) ring.far_end[(size_t)k] = prev[(size_t)k - 1];
    int infinitely_sharp = 0;
    const float vs = p.vertex_sharpness[(size_t)v];
    bool semi_sharp = vs > 0.0f && vs < kInfiniteSharpness;
    float sharpest = semi_sharp ? vs : 0.0f;
    for (int i = 0; i < n; ++i) {
        if (boundary && (i == 0 || i == k)) {
            ring.sharpness[(size_t)i] = kInfiniteSharpness;
            continue;
        }
        const float es = spia__catmark_edge_sharpness(&sh, v, ring.far_end[(size_t)i]);
        ring.sharpness[(size_t)i] = es;
        if (es >= kInfiniteSharpness) {
            ++infinitely_sharp;
        } else if (es > 0.0f) {
            semi_sharp = true;
            sharpest = std::max(sharpest, es);
        }
    }
    if (!semi_sharp || infinitely_sharp == 1) return 0;  // not semi-sharp, or a dart (Bfr)
    for (int j = 0; j < k; ++j) {  // face j between edges j (after the vertex) and j + 1
        ring.b[(size_t)j] = j;
        ring.a[(size_t)j] = (j + 1) % n;
        for (int e : {ring.a[(size_t)j], ring.b[(size_t)j]}) {
            int32_t *slot = &ring.edge_face[2 * (size_t)e];
            if (slot[0] < 0) slot[0] = j;
            else slot[1] = j;
        }
    }
    return std::max(1, std::min((int)std::ceil(sharpest), opt->quality));
}

// 6a on the threads, each row written into the table; the vertices it
// takes no longer need OpenSubdiv.
void fan_ring_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, const Prepared &p,
                   TableWriter &table, const unsigned char *on_boundary) {
    const int threads = opt->threads > 0 ? opt->threads : 1;
    const spia_catmark_sharpness sh = sharpness_view(p, opt);
    std::vector<std::vector<std::pair<int32_t, std::vector<Entry>>>> spill_of((size_t)threads);
    std::atomic<bool> out_of_memory(false);
    parallel_for(threads, m->vertex_count, 4096, [&](int64_t v0, int64_t v1, int thread) {
        try {
            Ring ring;
            RingScratch scratch;
            std::vector<int32_t> next, prev;
            std::vector<Entry> row;
            for (int32_t v = (int32_t)v0; v < (int32_t)v1; ++v) {
                if (table.length[(size_t)v] >= 0 || on_boundary[v] > 1) continue;
                const int levels = fan_ring(m, adj, p, sh, opt, v, on_boundary[v] == 1, next, prev, ring);
                if (levels == 0 || !ring_row(m, adj, ring, p.vertex_sharpness[(size_t)v], levels, p.sdc, scratch, row))
                    continue;
                table.write(v, row, spill_of[(size_t)thread]);
            }
        } catch (const std::bad_alloc &) {
            out_of_memory = true;
        }
    });
    if (out_of_memory) throw std::bad_alloc();
    for (auto &part_spill : spill_of)
        for (auto &r : part_spill) table.spilled.push_back(std::move(r));
}

// The closed-form rows (catmark_closed.c), on the threads, written into
// the table; the vertices they do not cover (no closed form) get length -1.
void closed_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, const Prepared &p,
                 TableWriter &table, unsigned char *on_boundary) {
    const spia_catmark_sharpness sh = sharpness_view(p, opt);
    const int threads = opt->threads > 0 ? opt->threads : 1;
    std::atomic<bool> out_of_memory(false);
    spia_stencils *s = table.s;
    parallel_for(threads, m->vertex_count, 4096, [&](int64_t v0, int64_t v1, int) {
        spia_row_scratch scratch;
        memset(&scratch, 0, sizeof scratch);
        scratch.build = 1;
        for (int32_t v = (int32_t)v0; v < (int32_t)v1 && !out_of_memory; ++v) {
            if (p.osd_of[v] < 0) continue;
            const int32_t len = spia__catmark_closed_row(m, adj, &sh, v, &scratch);
            if (scratch.on_boundary >= 0) on_boundary[v] = (unsigned char)scratch.on_boundary;
            if (len == SPIA__ROW_OUT_OF_MEMORY) {
                out_of_memory = true;
            } else if (len < 0 || len > s->offsets[v + 1] - s->offsets[v]) {
                table.length[(size_t)v] = -1;  // (a closed row is never longer than its room)
            } else {
                for (int32_t k = 0; k < len; ++k) {
                    s->indices[s->offsets[v] + k] = scratch.entries[k].column;
                    s->weights[s->offsets[v] + k] = scratch.entries[k].weight;
                }
                table.length[(size_t)v] = len;
            }
        }
        spia__row_scratch_free(&scratch);
    });
    if (out_of_memory) throw std::bad_alloc();
}

// 9. Each row's room.  For Loop, where every row comes from OpenSubdiv, the
//    distinct vertices of the vertex's faces, on which its limit point
//    alone depends.  For Catmull-Clark, where most rows have a closed form,
//    that row's length for a smooth interior vertex, 1 + sum (|f| - 2)
//    (and at least 3, a crease's): the table is made before it is known
//    which vertices need OpenSubdiv, and a row from it that does not fit
//    is kept aside (TableWriter).  Vertices no face uses: 1, or 3 where
//    two loose edges smooth them.
std::vector<int32_t> row_room(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                              const std::vector<int32_t> &loose_degree) {
    const int32_t n = m->vertex_count;
    std::vector<int32_t> room((size_t)n, 0);
    std::vector<int32_t> stamp;
    if (!p.blender) stamp.assign((size_t)p.osd_n, -1);
    for (int32_t v = 0; v < n; ++v) {
        const int32_t o = p.osd_of[v];
        int32_t count = 0;
        if (o < 0) {
            count = !loose_degree.empty() && loose_degree[v] == 2 ? 3 : 1;
        } else if (p.blender) {
            int64_t sum = 1;
            for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
                const int32_t f = adj->face_of_corner[adj->corner_of[i]];
                sum += adj->corner_start[f + 1] - adj->corner_start[f] - 2;
            }
            count = (int32_t)std::min<int64_t>(std::max<int64_t>(sum, 3), INT32_MAX);
        } else {
            for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
                const int32_t f = adj->face_of_corner[adj->corner_of[i]];
                for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c) {
                    const int32_t u = p.osd_of[m->face_vertices[c]];
                    if (stamp[u] != o) {
                        stamp[u] = o;
                        ++count;
                    }
                }
            }
        }
        room[(size_t)v] = count;
    }
    return room;
}

spia_result build(const spia_mesh *m, spia_adjacency *adj_lists, const spia_options *opt,
                  unsigned char *on_boundary, spia_stencils **out, spia_status *status) {
    const spia_adjacency *adj = adj_lists;
    Prepared p;
    spia_result r = prepare_sharpness(m, adj, opt, p);
    if (r != SPIA_OK) return r;
    const int32_t n = m->vertex_count;

    // 8. Vertices no face uses keep their position, except that Blender
    //    smooths a vertex with exactly two (loose) edges along them:
    //    (prev + 4 V + next) / 6.
    std::vector<int32_t> loose_degree, loose_ends;
    if (p.blender && p.osd_n < n && m->edge_count > 0) {
        loose_degree.assign((size_t)n, 0);
        loose_ends.assign(2 * (size_t)n, -1);
        for (int32_t e = 0; e < m->edge_count; ++e)
            for (int k = 0; k < 2; ++k) {
                int32_t v = m->edges[2 * (int64_t)e + k], w = m->edges[2 * (int64_t)e + 1 - k];
                if (p.osd_of[v] >= 0) continue;
                if (loose_degree[v] < 2) loose_ends[2 * (size_t)v + loose_degree[v]] = w;
                ++loose_degree[v];
            }
    }

    // 9. The table, with room for each row.
    TableWriter table;
    table.length = row_room(m, adj, p, loose_degree);
    int64_t capacity = 0;
    for (int32_t v = 0; v < n; ++v) capacity += table.length[(size_t)v];
    table.s = spia__stencils_alloc(n, capacity);
    if (!table.s)
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for %lld stencil weights",
                          (long long)capacity);
    std::unique_ptr<spia_stencils, void (*)(spia_stencils *)> owner(table.s, spia_stencils_free);
    for (int32_t v = 0; v < n; ++v) table.s->offsets[v + 1] = table.s->offsets[v] + table.length[(size_t)v];

    // The closed-form rows (Catmull-Clark) and the semi-sharp vertices of
    // one fan from their ring in the mesh (6a), and the vertices left for
    // OpenSubdiv (all, for Loop).
    if (p.blender) {
        closed_rows(m, adj, opt, p, table, on_boundary);
        fan_ring_rows(m, adj, opt, p, table, on_boundary);
    }
    std::vector<int32_t> wanted;
    for (int32_t o = 0; o < p.osd_n; ++o)
        if (!p.blender || table.length[(size_t)p.vertex_of[o]] < 0) wanted.push_back(o);

    // OpenSubdiv's refiner on the faces within two rings of those vertices
    // (the whole mesh when that is all of it), in a spatial order where the
    // mesh's scatters them (part_face_order); the adaptive rows (step 7).
    Part part;
    Evaluation ev;
    HeldRows held;
    if (!wanted.empty()) {
        std::vector<char> in_part = two_ring_faces(m, adj, p, wanted);
        if (std::find(in_part.begin(), in_part.end(), 0) == in_part.end()) in_part.clear();
        r = make_part(m, adj, opt, p, in_part, true, p.blender ? on_boundary : nullptr, part, status);
        if (r != SPIA_OK) return r;
        choose_evaluation(m, adj, opt, p, part, wanted, ev);
        r = adaptive_rows(m, adj, opt, p, ev, held, status);
        if (r != SPIA_OK) return r;
        r = ring_rows(opt, p, part, ev, held, status);
        if (r != SPIA_OK) return r;
    }
    // Vertices no face uses, and the adaptive rows.
    {
        std::vector<Entry> row;
        for (int32_t v = 0; v < n; ++v) {
            const int32_t o = p.osd_of[v];
            row.clear();
            if (o < 0) {
                const bool smoothed = !loose_degree.empty() && loose_degree[v] == 2;
                row.emplace_back(v, smoothed ? 4.0 / 6.0 : 1.0);
                if (smoothed)
                    for (int k = 0; k < 2; ++k) row.emplace_back(loose_ends[2 * (size_t)v + k], 1.0 / 6.0);
            } else if (!held.start.empty() && held.start[o] >= 0) {
                for (int32_t k = 0; k < held.size[o]; ++k)
                    row.emplace_back(held.indices[held.start[o] + k], held.weights[held.start[o] + k]);
            } else {
                continue;
            }
            table.write(v, row, table.spilled);
        }
        std::vector<int32_t>().swap(held.indices);
        std::vector<double>().swap(held.weights);
    }
    // The boundary vertices the closed rows did not learn, then (only
    // corner_start is needed from here on) the vertex lists make room.
    if (spia__boundary_vertices_unknown(m, adj, on_boundary, opt->threads > 0 ? opt->threads : 1) != SPIA_OK)
        throw std::bad_alloc();
    spia__adjacency_release_vertex_lists(adj_lists);
    adj = nullptr;
    if (part.refiner) {
        r = bfr_rows(m, adj_lists->corner_start, opt, p, part, ev, table, status);
        if (r != SPIA_OK) return r;
    }
    owner.release();
    spia_stencils *done = table.finish(n);
    if (!done) {
        spia_stencils_free(table.s);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the stencil table");
    }
    *out = done;
    spia__ok(status);
    return SPIA_OK;
}

// A point for Far::PrimvarRefiner.
struct Point {
    double p[3];
    void Clear(void * = nullptr) { p[0] = p[1] = p[2] = 0.0; }
    void AddWithWeight(const Point &src, float w) {
        for (int a = 0; a < 3; ++a) p[a] += (double)w * src.p[a];
    }
};

// Refines prepare()'s refiner uniformly to `levels` and carries the
// control points down with Far::PrimvarRefiner (to the last level's limit
// positions with `limit`).  The counts, counted in closed form, are checked
// against the refinement (ne < 0: not checked).  *last_points: the last
// level's points, in OpenSubdiv's order, inside `src` or `limit_points`.
spia_result refine_points(const spia_mesh *m, Prepared &p, int32_t levels, bool limit, int64_t nv, int64_t ne,
                          int64_t nf, std::vector<Point> &src, std::vector<Point> &limit_points,
                          const Point **last_points, spia__refine_clock *clock, spia_status *status) {
    Far::TopologyRefiner &refiner = *p.refiner;
    Far::TopologyRefiner::UniformOptions uniform(levels);
    uniform.fullTopologyInLastLevel = true;
    refiner.RefineUniform(uniform);
    const Far::TopologyLevel &last = refiner.GetLevel(levels);
    if (last.GetNumVertices() != nv || last.GetNumFaces() != nf || (ne >= 0 && last.GetNumEdges() != ne))
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1,
                          "refined to %d vertices and %d faces, not the %lld and %lld counted", last.GetNumVertices(),
                          last.GetNumFaces(), (long long)nv, (long long)nf);
    if (spia__refine_tick(clock, 0)) return spia__refine_cancelled(status, clock);
    src.resize((size_t)refiner.GetNumVerticesTotal());
    for (int32_t o = 0; o < p.osd_n; ++o)
        for (int a = 0; a < 3; ++a) src[o].p[a] = m->positions[3 * (int64_t)p.vertex_of[o] + a];
    Far::PrimvarRefinerReal<float> primvar(refiner);
    Point *level_src = src.data();
    for (int level = 1; level <= levels; ++level) {
        Point *level_dst = level_src + refiner.GetLevel(level - 1).GetNumVertices();
        primvar.Interpolate(level, level_src, level_dst);
        level_src = level_dst;
        // With `limit`, the last level is done when its limit is.
        if ((!limit || level < levels) && spia__refine_level_done(clock, level))
            return spia__refine_cancelled(status, clock);
    }
    *last_points = level_src;
    if (limit) {
        limit_points.resize((size_t)last.GetNumVertices());
        Point *limit_dst = limit_points.data();
        primvar.Limit(level_src, limit_dst);
        *last_points = limit_points.data();
        if (spia__refine_level_done(clock, levels)) return spia__refine_cancelled(status, clock);
    }
    return SPIA_OK;
}

// The output's index of the last level's vertex i: the control vertices'
// children at the caller's indices, then the others in OpenSubdiv's order.
int32_t refined_index(const Prepared &p, int32_t n, int32_t i) { return i < p.osd_n ? p.vertex_of[i] : n + (i - p.osd_n); }

// Writes the last level's points (the caller's vertices that OpenSubdiv
// did not take, loose ones, where they are) and its faces, each of
// face_size corners.
spia_result write_refined(const spia_mesh *m, const Prepared &p, const Far::TopologyLevel &last, const Point *points,
                          int face_size, float *positions, int32_t *faces, spia_status *status) {
    const int32_t n = m->vertex_count;
    for (int32_t v = 0; v < n; ++v)
        if (p.osd_of[v] < 0)
            for (int a = 0; a < 3; ++a) positions[3 * (int64_t)v + a] = m->positions[3 * (int64_t)v + a];
    for (int32_t i = 0; i < last.GetNumVertices(); ++i)
        for (int a = 0; a < 3; ++a) positions[3 * (int64_t)refined_index(p, n, i) + a] = (float)points[i].p[a];
    int64_t k = 0;
    for (int32_t f = 0; f < last.GetNumFaces(); ++f) {
        Far::ConstIndexArray fv = last.GetFaceVertices(f);
        if (fv.size() != face_size)
            return spia__fail(status, SPIA_ERROR_INTERNAL, f, "refined face %d has %d vertices", (int)f, fv.size());
        for (int c = 0; c < face_size; ++c) faces[k++] = refined_index(p, n, fv[c]);
    }
    return SPIA_OK;
}

// The output's vertex count from the last level's nv (the caller's
// vertices, then the refined ones that are not control vertices), refused
// when it or the longest output array (`longest` entries) passes int32.
spia_result refined_total(const spia_mesh *m, const Prepared &p, int32_t levels, int64_t nv, int64_t nf,
                          int64_t longest, int32_t *vertex_count, spia_status *status) {
    const int64_t total = m->vertex_count + (nv - p.osd_n);
    if (total > INT32_MAX || longest > INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "%d levels make %lld faces, too many", (int)levels,
                          (long long)nf);
    *vertex_count = (int32_t)total;
    return SPIA_OK;
}

spia_result refine(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t levels,
                   int32_t *vertex_count, int32_t *face_count, float *positions, int32_t *faces,
                   spia__refine_clock *clock, spia_status *status) {
    Prepared p;
    spia_result r = prepare(m, adj, opt, p, status);
    if (r != SPIA_OK) return r;
    // The counts in closed form from the control mesh, so that asking for
    // them costs no refinement: a uniform Loop step puts a vertex on every
    // edge and splits every triangle in four (V' = V + E, E' = 2 E + 3 F,
    // F' = 4 F).
    const Far::TopologyLevel &base = p.refiner->GetLevel(0);
    int64_t nv = base.GetNumVertices(), ne = base.GetNumEdges(), nf = base.GetNumFaces();
    for (int32_t l = 0; l < levels; ++l) {
        nv += ne;
        ne = 2 * ne + 3 * nf;
        nf *= 4;
    }
    // Child vertices of vertices come first at every level, in their parents'
    // order, so the first osd_n vertices of the last level are the control
    // vertices; the output puts them at the caller's indices and appends the
    // others.
    if ((r = refined_total(m, p, levels, nv, nf, 3 * nf, vertex_count, status)) != SPIA_OK) return r;
    *face_count = (int32_t)nf;
    if (!positions) return SPIA_OK;
    std::vector<Point> src, limit;
    const Point *points = nullptr;
    if ((r = refine_points(m, p, levels, true, nv, -1, nf, src, limit, &points, clock, status)) != SPIA_OK) return r;
    if ((r = write_refined(m, p, p.refiner->GetLevel(levels), points, 3, positions, faces, status)) != SPIA_OK)
        return r;
    spia__ok(status);
    return SPIA_OK;
}

// Catmull-Clark refinement of the control mesh (spia_subdivide): OpenSubdiv's
// uniform refinement of the refiner prepare() makes, so the refined mesh
// carries the cage's sharpness one step softer per level and its limit
// surface is the cage's.  Child vertices of vertices come first at every
// level, in their parents' order: the output puts them at the caller's
// indices, then the others in OpenSubdiv's order.  The sharpness goes back
// into Blender's creases (c = sqrt(s / 10)), with the two-edge rule
// (applied again when the mesh is read) taken off the vertex creases
// beforehand, so that reading the refined mesh gives the refined sharpness.
spia_result subdivide(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t levels,
                      int32_t *vertex_count, int32_t *face_count, int32_t *edge_count, float *positions,
                      int32_t *face_vertices, int32_t *edges, float *edge_creases, float *vertex_creases,
                      spia__refine_clock *clock, spia_status *status) {
    Prepared p;
    spia_result r = prepare(m, adj, opt, p, status);
    if (r != SPIA_OK) return r;
    // Counts in closed form: a Catmull-Clark step puts a vertex on every edge
    // and face, splits an n-gon into n quads and makes 2 edges of each edge
    // and one of each face corner.
    const Far::TopologyLevel &base = p.refiner->GetLevel(0);
    int64_t nv = base.GetNumVertices(), ne = base.GetNumEdges(), nf = base.GetNumFaces(), corners = 0;
    for (int f = 0; f < base.GetNumFaces(); ++f) corners += base.GetFaceVertices(f).size();
    for (int32_t l = 0; l < levels; ++l) {
        nv += ne + nf;
        ne = 2 * ne + corners;
        nf = corners;
        corners = 4 * nf;
    }
    const int32_t n = m->vertex_count;
    if ((r = refined_total(m, p, levels, nv, nf, std::max(4 * nf, 2 * ne), vertex_count, status)) != SPIA_OK) return r;
    *face_count = (int32_t)nf;
    *edge_count = (int32_t)ne;
    if (!positions) return SPIA_OK;
    std::vector<Point> src, unused;
    const Point *points = nullptr;
    if ((r = refine_points(m, p, levels, false, nv, ne, nf, src, unused, &points, clock, status)) != SPIA_OK)
        return r;
    const Far::TopologyLevel &last = p.refiner->GetLevel(levels);
    if ((r = write_refined(m, p, last, points, 4, positions, face_vertices, status)) != SPIA_OK) return r;
    auto out_index = [&](int32_t i) { return refined_index(p, n, i); };
    const bool creased = !opt->ignore_creases;
    auto crease_of = [](float s) {
        return s >= kInfiniteSharpness ? 1.0f : (s > 0.0f ? (float)std::sqrt((double)s / 10.0) : 0.0f);
    };
    // Boundary and non-manifold edges OpenSubdiv makes infinitely sharp by
    // itself, as it will again when the refined mesh is read: they are not
    // written as creases, which would bring Blender's two-edge rule down on
    // every one-face corner of a boundary.
    auto written = [&](Far::Index e) {
        if (!creased || last.IsEdgeBoundary(e) || last.IsEdgeNonManifold(e)) return 0.0f;
        return crease_of(last.GetEdgeSharpness(e));
    };
    if (edges || edge_creases)
        for (int32_t e = 0; e < last.GetNumEdges(); ++e) {
            Far::ConstIndexArray ev = last.GetEdgeVertices(e);
            if (edges) {
                edges[2 * (int64_t)e] = out_index(ev[0]);
                edges[2 * (int64_t)e + 1] = out_index(ev[1]);
            }
            if (edge_creases) edge_creases[e] = written(e);
        }
    if (vertex_creases) {
        // Loose vertices keep theirs (the refined mesh has no loose edges,
        // so vertices they sharpened carry it as a vertex crease below).
        for (int32_t v = 0; v < n; ++v)
            vertex_creases[v] = (p.osd_of[v] < 0 && creased && m->vertex_creases) ? m->vertex_creases[v] : 0.0f;
        for (int32_t i = 0; i < last.GetNumVertices(); ++i) {
            float s = last.GetVertexSharpness(i);
            if (s <= 0.0f || !creased) {
                vertex_creases[out_index(i)] = 0.0f;
                continue;
            }
            Far::ConstIndexArray ve = last.GetVertexEdges(i);
            if (s < kInfiniteSharpness && p.blender && ve.size() == 2) {
                // Blender adds the smaller sharpness of a vertex's two edges.
                const float added = std::min(crease_to_sharpness(written(ve[0])), crease_to_sharpness(written(ve[1])));
                s = std::max(0.0f, s - added);
            }
            vertex_creases[out_index(i)] = crease_of(s);
        }
    }
    spia__ok(status);
    return SPIA_OK;
}

// Limit stencils at samples inside the faces: per ptex face (a quad, or each
// corner's sub-quad of another polygon), samples_per_edge^2 points at the
// centres of a regular grid over (s, t), in t, then s order, on Blender's
// patches at quality.  Each face's rows come as one dense block over the
// face's control vertices.
//
// Most faces: Bfr, each face's surface from its own neighbourhood, with its
// approximation levels (sharp and smooth) at quality; irregular patches are
// shared among faces of the same topology, so this costs little more than
// evaluating the basis.  Bfr builds the same patches as Blender's adaptive
// refinement except at faces with a corner that is non-manifold, a smooth
// boundary vertex of one face, sharpened itself or meets three or more
// creased edges (there its sharpness decays within the isolation level;
// the differences measured up to 1e-3 at quality 1, 1e-8 at quality 3).
// Those faces go through OpenSubdiv's adaptive patch table as
// LimitStencilTableFactory builds it (Gregory end caps, the refined and
// local points' stencils), on the part of the mesh within two rings of
// them.  The factory's sums are reproduced term by term (the same order,
// so the same rows) without its search for each entry's place.
struct FaceBlocks {
    std::vector<int32_t> columns;
    std::vector<double> weights;
};

struct SampleGrid {
    int per_face = 0;
    std::vector<double> s, t;
    // The centres of per_edge^2 cells, or with `corners` per_edge points on
    // each edge from 0 to 1 (at least 2).
    SampleGrid(int per_edge, bool corners) : per_face(per_edge * per_edge), s((size_t)per_face), t((size_t)per_face) {
        for (int j = 0; j < per_edge; ++j)
            for (int i = 0; i < per_edge; ++i) {
                s[(size_t)(j * per_edge + i)] = corners ? (double)i / (per_edge - 1) : (i + 0.5) / per_edge;
                t[(size_t)(j * per_edge + i)] = corners ? (double)j / (per_edge - 1) : (j + 0.5) / per_edge;
            }
    }
};

// OpenSubdiv's adaptive patches on `refiner` (refined here) for the faces
// marked in `wanted`: per ptex face of each, its block, columns in the
// refiner's numbering.
spia_result far_blocks(Far::TopologyRefiner &refiner, const spia_options *opt, const SampleGrid &grid,
                       const std::vector<char> &wanted, std::vector<std::vector<FaceBlocks>> &out,
                       spia_status *status) {
    Far::TopologyRefiner::AdaptiveOptions adaptive(opt->quality);
    adaptive.useInfSharpPatch = true;
    adaptive.considerFVarChannels = false;
    refiner.RefineAdaptive(adaptive);
    Far::PtexIndices ptex(refiner);
    typedef Far::StencilTableReal<double> Table;
    typedef Far::StencilTableFactoryReal<double> TableFactory;
    TableFactory::Options table_options;
    table_options.generateIntermediateLevels = true;
    table_options.generateControlVerts = true;
    table_options.generateOffsets = true;
    std::unique_ptr<const Table> refined(TableFactory::Create(refiner, table_options));
    Far::PatchTableFactory::Options patch_options;
    patch_options.SetPatchPrecision<double>();
    patch_options.includeBaseLevelIndices = true;
    patch_options.SetEndCapType(Far::PatchTableFactory::Options::ENDCAP_GREGORY_BASIS);
    patch_options.useInfSharpPatch = true;
    std::unique_ptr<const Far::PatchTable> patches(Far::PatchTableFactory::Create(refiner, patch_options));
    if (!refined || !patches)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv built no patches for the samples");
    const Table *points = refined.get();
    std::unique_ptr<const Table> appended;
    const Table *local = patches->GetLocalPointStencilTable<double>();
    if (local && refined->GetNumStencils() == refiner.GetNumVerticesTotal()) {
        appended.reset(TableFactory::AppendLocalPointStencilTable(refiner, refined.get(), local));
        if (!appended) return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv built no local point stencils");
        points = appended.get();
        refined.reset();
    }
    Far::PatchMap map(*patches);
    const int per_face = grid.per_face;
    const Far::TopologyLevel &base = refiner.GetLevel(0);
    const int32_t n = base.GetNumVertices(), faces = base.GetNumFaces();
    std::vector<Far::ConstIndexArray> cvs((size_t)per_face);
    std::vector<double> basis((size_t)per_face * 20);
    std::vector<int32_t> stamp((size_t)n, -1), slot((size_t)n, 0);
    out.assign((size_t)faces, std::vector<FaceBlocks>());
    int32_t stamp_id = 0;
    for (int32_t face = 0; face < faces; ++face) {
        if (!wanted[(size_t)face]) continue;
        const int size = base.GetFaceVertices(face).size();
        const int subs = size == 4 ? 1 : size;
        out[(size_t)face].resize((size_t)subs);
        for (int sub = 0; sub < subs; ++sub, ++stamp_id) {
            const int f = ptex.GetFaceId(face) + sub;
            FaceBlocks &fb = out[(size_t)face][(size_t)sub];
            for (int j = 0; j < per_face; ++j) {
                const Far::PatchMap::Handle *handle = map.FindPatch(f, grid.s[(size_t)j], grid.t[(size_t)j]);
                if (!handle)
                    return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv has no patch under a sample");
                cvs[(size_t)j] = patches->GetPatchVertices(*handle);
                if (cvs[(size_t)j].size() > 20)
                    return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "a patch of %d points", cvs[(size_t)j].size());
                patches->EvaluateBasis<double>(*handle, grid.s[(size_t)j], grid.t[(size_t)j], &basis[(size_t)j * 20]);
                for (int k = 0; k < cvs[(size_t)j].size(); ++k) {
                    const Far::StencilReal<double> point = points->GetStencil(cvs[(size_t)j][k]);
                    const Far::Index *idx = point.GetVertexIndices();
                    for (int e = 0; e < point.GetSize(); ++e) {
                        const Far::Index c = idx[e];
                        if (c < 0 || c >= n)
                            return spia__fail(status, SPIA_ERROR_INTERNAL, -1,
                                              "OpenSubdiv sample stencil refers to point %d, not a control vertex",
                                              (int)c);
                        if (stamp[(size_t)c] != stamp_id) {
                            stamp[(size_t)c] = stamp_id;
                            slot[(size_t)c] = (int32_t)fb.columns.size();
                            fb.columns.push_back(c);
                        }
                    }
                }
            }
            const size_t width = fb.columns.size();
            fb.weights.assign(width * (size_t)per_face, 0.0);
            for (int j = 0; j < per_face; ++j) {
                double *row = &fb.weights[(size_t)j * width];
                for (int k = 0; k < cvs[(size_t)j].size(); ++k) {
                    const double b = basis[(size_t)j * 20 + (size_t)k];
                    if (b == 0.0) continue;
                    const Far::StencilReal<double> point = points->GetStencil(cvs[(size_t)j][k]);
                    const Far::Index *idx = point.GetVertexIndices();
                    const double *w = point.GetWeights();
                    for (int e = 0; e < point.GetSize(); ++e)
                        if (w[e] != 0.0) row[slot[(size_t)idx[e]]] += b * w[e];
                }
            }
        }
    }
    return SPIA_OK;
}

// The faces Bfr does not reproduce (see above), as a mark per mesh face.
std::vector<char> faces_for_far(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, bool &any) {
    const Far::TopologyLevel &base = p.refiner->GetLevel(0);
    std::vector<char> special((size_t)p.osd_n, 0), face((size_t)m->face_count, 0);
    for (int32_t o = 0; o < p.osd_n; ++o) {
        bool s = base.IsVertexNonManifold(o) || base.GetVertexSharpness(o) > 0.0f ||
                 (base.IsVertexBoundary(o) && base.GetVertexFaces(o).size() == 1);
        if (!s) {
            Far::ConstIndexArray ve = base.GetVertexEdges(o);
            int creased = 0;
            for (int k = 0; k < ve.size(); ++k) creased += base.GetEdgeSharpness(ve[k]) > 0.0f;
            s = creased >= 3;
        }
        special[(size_t)o] = s;
    }
    any = false;
    for (int32_t f = 0; f < m->face_count; ++f)
        for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c)
            if (special[(size_t)p.osd_of[m->face_vertices[c]]]) {
                face[(size_t)f] = 1;
                any = true;
                break;
            }
    return face;
}

// What a sample block consumer's nonzero return stops the blocks with.
spia_result emit_stopped(int stop, spia_status *status) {
    if (stop == SPIA_ERROR_CANCELLED)
        return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the sample stencils");
    if (stop == SPIA_ERROR_INTERNAL)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "the sample stencils do not match the cage's faces");
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
}

spia_result surface_blocks(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t per_edge,
                           bool corners, spia__sample_block_fn emit, void *user, spia_status *status) {
    Prepared p;
    spia_result r = prepare(m, adj, opt, p, status);
    if (r != SPIA_OK) return r;
    const SampleGrid grid(per_edge, corners);
    const int per_face = grid.per_face;

    // The faces for OpenSubdiv's patch table, on their part of the mesh.
    bool any_far = false;
    const std::vector<char> far_face = faces_for_far(m, adj, p, any_far);
    std::vector<std::vector<FaceBlocks>> far_out;  // per face of the part
    std::vector<int32_t> local_face_of;            // mesh face -> face of the part
    Part part;
    if (any_far) {
        std::vector<int32_t> marked;
        for (int32_t f = 0; f < m->face_count; ++f)
            if (far_face[(size_t)f])
                for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c)
                    marked.push_back(p.osd_of[m->face_vertices[c]]);
        std::sort(marked.begin(), marked.end());
        marked.erase(std::unique(marked.begin(), marked.end()), marked.end());
        if ((r = make_part(m, adj, opt, p, two_ring_faces(m, adj, p, marked), false, nullptr, part, status)) != SPIA_OK)
            return r;
        const int32_t local_faces = part.refiner->GetLevel(0).GetNumFaces();
        std::vector<char> wanted((size_t)local_faces, 0);
        for (int32_t i = 0; i < local_faces; ++i) wanted[(size_t)i] = far_face[(size_t)part.mesh_face(i)];
        if ((r = far_blocks(*part.refiner, opt, grid, wanted, far_out, status)) != SPIA_OK) return r;
        local_face_of.assign((size_t)m->face_count, -1);
        for (int32_t i = 0; i < local_faces; ++i) local_face_of[(size_t)part.mesh_face(i)] = i;
    }

    const Far::TopologyRefiner &refiner = *p.refiner;
    Bfr::SurfaceFactory::Options qopt;
    qopt.SetApproxLevelSharp(opt->quality).SetApproxLevelSmooth(opt->quality);
    Bfr::RefinerSurfaceFactory<> factory(refiner, qopt);
    Bfr::Surface<double> srf;
    std::vector<Far::Index> cv;
    std::vector<double> w;
    std::vector<int32_t> stamp((size_t)p.osd_n, -1), slot((size_t)p.osd_n, 0), columns;
    std::vector<double> block;
    int64_t ptex = 0;
    for (int32_t f = 0; f < m->face_count; ++f) {
        if (any_far && far_face[(size_t)f]) {
            const std::vector<FaceBlocks> &subs = far_out[(size_t)local_face_of[(size_t)f]];
            for (const FaceBlocks &fb : subs) {
                columns.resize(fb.columns.size());
                for (size_t i = 0; i < columns.size(); ++i) columns[i] = p.vertex_of[(size_t)part.osd(fb.columns[i])];
                if (int stop = emit(user, ptex++, (int32_t)columns.size(), columns.data(), fb.weights.data()))
                    return emit_stopped(stop, status);
            }
            continue;
        }
        if (!factory.InitVertexSurface(f, &srf) || !srf.IsValid())
            return spia__fail(status, SPIA_ERROR_INTERNAL, f, "OpenSubdiv built no limit surface for face %d", (int)f);
        cv.resize((size_t)srf.GetNumControlPoints());
        w.resize(cv.size());
        srf.GetControlPointIndices(cv.data());
        columns.clear();
        for (size_t k = 0; k < cv.size(); ++k) {
            const Far::Index c = cv[k];
            if (stamp[(size_t)c] != f) {
                stamp[(size_t)c] = f;
                slot[(size_t)c] = (int32_t)columns.size();
                columns.push_back(c);
            }
        }
        const Bfr::Parameterization param = srf.GetParameterization();
        const int sub_faces = param.HasSubFaces() ? param.GetFaceSize() : 1;
        const size_t width = columns.size();
        for (size_t i = 0; i < width; ++i) columns[i] = p.vertex_of[(size_t)columns[i]];
        for (int sub = 0; sub < sub_faces; ++sub, ++ptex) {
            block.assign(width * (size_t)per_face, 0.0);
            for (int j = 0; j < per_face; ++j) {
                double uv[2], st[2] = {grid.s[(size_t)j], grid.t[(size_t)j]};
                if (param.HasSubFaces())
                    param.ConvertNormalizedSubFaceToCoord(sub, st, uv);
                else
                    uv[0] = st[0], uv[1] = st[1];
                srf.EvaluateStencil(uv, w.data());
                double *row = &block[(size_t)j * width];
                for (size_t k = 0; k < cv.size(); ++k) row[slot[(size_t)cv[k]]] += w[k];
            }
            if (int stop = emit(user, ptex, (int32_t)width, columns.data(), block.data()))
                return emit_stopped(stop, status);
        }
    }
    spia__ok(status);
    return SPIA_OK;
}

// The blocks as a stencil table: rows in ptex order, exact zeros dropped,
// columns sorted.
struct RowsOut {
    std::vector<int64_t> offsets{0};
    std::vector<int32_t> indices;
    std::vector<double> weights;
    int32_t per = 0;
    static int add(void *user, int64_t, int32_t width, const int32_t *columns, const double *w) {
        RowsOut &o = *static_cast<RowsOut *>(user);
        try {
            for (int32_t j = 0; j < o.per; ++j) {
                for (int32_t i = 0; i < width; ++i)
                    if (w[(size_t)j * width + i] != 0.0) {
                        o.indices.push_back(columns[i]);
                        o.weights.push_back(w[(size_t)j * width + i]);
                    }
                o.offsets.push_back((int64_t)o.indices.size());
            }
        } catch (const std::bad_alloc &) {
            return SPIA_ERROR_OUT_OF_MEMORY;
        }
        return 0;
    }
};

spia_result surface(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t per_edge,
                    spia_stencils **out, spia_status *status) {
    const int64_t rows = spia_surface_sample_count(m, per_edge);
    if (rows > INT32_MAX / 64)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "%lld samples are too many (at most %d): lower samples_per_edge", (long long)rows,
                          INT32_MAX / 64);
    RowsOut o;
    o.per = per_edge * per_edge;
    o.offsets.reserve((size_t)rows + 1);
    spia_result r = surface_blocks(m, adj, opt, per_edge, false, RowsOut::add, &o, status);
    if (r != SPIA_OK) return r;
    if ((int64_t)o.offsets.size() != rows + 1)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv made %lld sample stencils for %lld samples",
                          (long long)o.offsets.size() - 1, (long long)rows);
    spia_stencils *s = spia__stencils_alloc((int32_t)rows, (int64_t)o.weights.size());
    if (!s) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
    std::copy(o.offsets.begin(), o.offsets.end(), s->offsets);
    std::copy(o.indices.begin(), o.indices.end(), s->indices);
    std::copy(o.weights.begin(), o.weights.end(), s->weights);
    s->nnz = (int64_t)o.weights.size();
    spia__stencils_canonicalize(s);
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

// spia_sharpness: prepare_sharpness's values in the mesh's own numbering,
// the creased face edges sorted by their (smaller, larger) end.
spia_result sharpness(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, bool two_edge_rule,
                      int32_t *count, int32_t *pairs, float *edge_sharpness, float *vertex_sharpness,
                      spia_status *status) {
    Prepared p;
    spia_result r = prepare_sharpness(m, adj, opt, p, two_edge_rule);
    if (r != SPIA_OK) return r;
    std::vector<std::pair<std::pair<int32_t, int32_t>, float>> creases;
    creases.reserve(p.crease_weights.size());
    for (size_t k = 0; k < p.crease_weights.size(); ++k) {
        const int32_t a = p.vertex_of[(size_t)p.crease_pairs[2 * k]], b = p.vertex_of[(size_t)p.crease_pairs[2 * k + 1]];
        creases.push_back(std::make_pair(std::make_pair(std::min(a, b), std::max(a, b)), p.crease_weights[k]));
    }
    std::sort(creases.begin(), creases.end());
    *count = (int32_t)creases.size();
    for (size_t k = 0; k < creases.size(); ++k) {
        if (pairs) {
            pairs[2 * k] = creases[k].first.first;
            pairs[2 * k + 1] = creases[k].first.second;
        }
        if (edge_sharpness) edge_sharpness[k] = creases[k].second;
    }
    if (vertex_sharpness)
        for (int32_t v = 0; v < m->vertex_count; ++v) vertex_sharpness[v] = p.vertex_sharpness[(size_t)v];
    spia__ok(status);
    return SPIA_OK;
}

}  // namespace

extern "C" spia_result spia__osd_limit_stencils(const spia_mesh *mesh, spia_adjacency *adj,
                                                    const spia_options *options, unsigned char *on_boundary,
                                                    spia_stencils **out, spia_status *status) {
    *out = nullptr;
    try {
        return build(mesh, adj, options, on_boundary, out, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing limit stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing limit stencils");
    }
}

extern "C" spia_result spia__osd_refine_limit(const spia_mesh *mesh, const spia_adjacency *adj,
                                              const spia_options *options, int32_t levels, int32_t *vertex_count,
                                              int32_t *face_count, float *positions, int32_t *faces,
                                              spia__refine_clock *clock, spia_status *status) {
    try {
        return refine(mesh, adj, options, levels, vertex_count, face_count, positions, faces, clock, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure refining the surface");
    }
}

extern "C" spia_result spia__osd_surface_stencils(const spia_mesh *mesh, const spia_adjacency *adj,
                                                  const spia_options *options, int32_t samples_per_edge,
                                                  spia_stencils **out, spia_status *status) {
    *out = nullptr;
    try {
        return surface(mesh, adj, options, samples_per_edge, out, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing sample stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing sample stencils");
    }
}

extern "C" spia_result spia__osd_surface_blocks(const spia_mesh *mesh, const spia_adjacency *adj,
                                                const spia_options *options, int32_t samples_per_edge,
                                                int32_t corners, spia__sample_block_fn emit, void *user,
                                                spia_status *status) {
    if (corners && samples_per_edge < 2)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "a grid with corners needs two points an edge");
    try {
        return surface_blocks(mesh, adj, options, samples_per_edge, corners != 0, emit, user, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing sample stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing sample stencils");
    }
}

extern "C" spia_result spia__osd_subdivide(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                           int32_t levels, int32_t *vertex_count, int32_t *face_count,
                                           int32_t *edge_count, float *positions, int32_t *face_vertices,
                                           int32_t *edges, float *edge_creases, float *vertex_creases,
                                           spia__refine_clock *clock, spia_status *status) {
    try {
        return subdivide(mesh, adj, options, levels, vertex_count, face_count, edge_count, positions, face_vertices,
                         edges, edge_creases, vertex_creases, clock, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory subdividing the cage");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure subdividing the cage");
    }
}

extern "C" spia_result spia__osd_sharpness(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                           int two_edge_rule, int32_t *count, int32_t *pairs, float *edge_sharpness,
                                           float *vertex_sharpness, spia_status *status) {
    try {
        return sharpness(mesh, adj, options, two_edge_rule != 0, count, pairs, edge_sharpness, vertex_sharpness,
                         status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory reading the creases");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure reading the creases");
    }
}
