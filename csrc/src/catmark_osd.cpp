// The library's only C++ file: Catmull-Clark limit stencils from OpenSubdiv,
// set up exactly as Blender's Subdivision Surface modifier sets it up when
// "Use Limit Surface" is on, so that the limit points these stencils give
// are the points the modifier shows for the control vertices.
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
//    first face (in face order) that uses it.

#include "internal.h"

#include <opensubdiv/far/patchTableFactory.h>
#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <new>
#include <vector>

using namespace OpenSubdiv;

namespace {

typedef Far::LimitStencilTableFactoryReal<double> LimitFactory;
typedef Far::LimitStencilTableReal<double> LimitTable;

const float kInfiniteSharpness = Sdc::Crease::SHARPNESS_INFINITE;  // 10

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

spia_result build(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, spia_stencils **out,
                  spia_status *status) {
    const int32_t n = m->vertex_count;
    const bool use_creases = !opt->ignore_creases;

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
    const int32_t *fv = m->face_vertices;
    if (renumbered) {
        remapped.resize((size_t)adj->corner_count);
        for (int64_t c = 0; c < adj->corner_count; ++c) remapped[c] = osd_of[m->face_vertices[c]];
        fv = remapped.data();
    }

    // 2. Edge sharpness of face edges; loose edges sharpen their end points.
    std::vector<float> vertex_sharpness(osd_n, 0.0f);
    std::vector<int32_t> crease_pairs;
    std::vector<float> crease_weights;
    // Per vertex, its creased face edges as (other end, sharpness), for the
    // two-edge rule below.
    std::vector<std::vector<std::pair<int32_t, float>>> creased_at;
    bool any_edge_crease = false;
    for (int32_t e = 0; e < m->edge_count; ++e) {
        int32_t a = m->edges[2 * (int64_t)e], b = m->edges[2 * (int64_t)e + 1];
        bool face_edge = osd_of[a] >= 0 && osd_of[b] >= 0 && is_face_edge(m, adj, a, b);
        if (!face_edge) {
            if (osd_of[a] >= 0) vertex_sharpness[osd_of[a]] = INFINITY;
            if (osd_of[b] >= 0) vertex_sharpness[osd_of[b]] = INFINITY;
            continue;
        }
        if (!use_creases || !m->edge_creases) continue;
        float s = crease_to_sharpness(m->edge_creases[e]);
        if (s < 1e-6f) continue;
        if (!any_edge_crease) {
            creased_at.resize(osd_n);
            any_edge_crease = true;
        }
        crease_pairs.push_back(osd_of[a]);
        crease_pairs.push_back(osd_of[b]);
        crease_weights.push_back(s);
        creased_at[osd_of[a]].push_back(std::make_pair(osd_of[b], s));
        creased_at[osd_of[b]].push_back(std::make_pair(osd_of[a], s));
    }

    // 3. Vertex sharpness: infinite at loose-edge ends; else the vertex
    //    crease, plus the smaller sharpness of exactly two incident edges.
    std::vector<int32_t> corner_indices;
    std::vector<float> corner_weights;
    for (int32_t o = 0; o < osd_n; ++o) {
        int32_t v = vertex_of[o];
        float s;
        if (vertex_sharpness[o] == INFINITY) {
            s = kInfiniteSharpness;
        } else {
            s = (use_creases && m->vertex_creases) ? crease_to_sharpness(m->vertex_creases[v]) : 0.0f;
            if (any_edge_crease && !creased_at[o].empty()) {
                // Distinct neighbours along face edges.
                int32_t nb[3];
                int count = 0;
                for (int64_t i = adj->first[v]; i < adj->first[v + 1] && count < 3; ++i) {
                    int64_t c = adj->corner_of[i];
                    int32_t cand[2] = {osd_of[spia__corner_prev(m, adj, c)], osd_of[spia__corner_next(m, adj, c)]};
                    for (int32_t w : cand) {
                        bool seen = false;
                        for (int k = 0; k < count; ++k) seen = seen || nb[k] == w;
                        if (!seen && count < 3) nb[count++] = w;
                    }
                }
                if (count == 2) {
                    float e_s[2] = {0.0f, 0.0f};
                    for (int k = 0; k < 2; ++k)
                        for (const auto &pr : creased_at[o])
                            if (pr.first == nb[k]) e_s[k] = pr.second;
                    s += std::min(e_s[0], e_s[1]);
                    s = std::min(s, 10.0f);
                }
            }
        }
        if (s > 0.0f) {
            corner_indices.push_back(o);
            corner_weights.push_back(s);
        }
    }

    // 4. The refiner.
    Far::TopologyDescriptor desc;
    desc.numVertices = osd_n;
    desc.numFaces = m->face_count;
    desc.numVertsPerFace = m->face_sizes;
    desc.vertIndicesPerFace = fv;
    desc.numCreases = (int)crease_weights.size();
    desc.creaseVertexIndexPairs = crease_pairs.empty() ? nullptr : crease_pairs.data();
    desc.creaseWeights = crease_weights.empty() ? nullptr : crease_weights.data();
    desc.numCorners = (int)corner_weights.size();
    desc.cornerVertexIndices = corner_indices.empty() ? nullptr : corner_indices.data();
    desc.cornerWeights = corner_weights.empty() ? nullptr : corner_weights.data();

    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS
                                        ? Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER
                                        : Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    sdc.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    sdc.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);

    typedef Far::TopologyRefinerFactory<Far::TopologyDescriptor> RefinerFactory;
    std::unique_ptr<Far::TopologyRefiner> refiner(
        RefinerFactory::Create(desc, RefinerFactory::Options(Sdc::SCHEME_CATMARK, sdc)));
    if (!refiner)
        return spia__fail(status, SPIA_ERROR_TOPOLOGY, -1, "OpenSubdiv rejected the mesh topology");

    Far::TopologyRefiner::AdaptiveOptions adaptive(opt->quality);
    adaptive.useInfSharpPatch = true;
    adaptive.considerFVarChannels = false;
    refiner->RefineAdaptive(adaptive);

    // 5. One limit location per used vertex: its corner of its first face.
    static const double corner_s[4] = {0.0, 1.0, 1.0, 0.0};
    static const double corner_t[4] = {0.0, 0.0, 1.0, 1.0};
    Far::PtexIndices ptex(*refiner);
    LimitFactory::LocationArrayVec locations((size_t)osd_n);
    for (int32_t o = 0; o < osd_n; ++o) {
        int32_t v = vertex_of[o];
        int64_t c = adj->corner_of[adj->first[v]];
        int32_t f = adj->face_of_corner[c];
        int32_t k = (int32_t)(c - adj->corner_start[f]);
        LimitFactory::LocationArray &loc = locations[o];
        loc.numLocations = 1;
        if (m->face_sizes[f] == 4) {
            loc.ptexIdx = ptex.GetFaceId(f);
            loc.s = &corner_s[k];
            loc.t = &corner_t[k];
        } else {
            loc.ptexIdx = ptex.GetFaceId(f) + k;
            loc.s = &corner_s[0];
            loc.t = &corner_t[0];
        }
    }
    LimitFactory::Options limit_options;
    limit_options.generate1stDerivatives = false;
    limit_options.generate2ndDerivatives = false;
    std::unique_ptr<const LimitTable> table(LimitFactory::Create(*refiner, locations, nullptr, nullptr, limit_options));
    if (!table || table->GetNumStencils() != osd_n)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv returned %d limit stencils for %d vertices",
                          table ? table->GetNumStencils() : -1, (int)osd_n);

    // 6. Into the library's table, in the caller's vertex numbering.
    const std::vector<int> &sizes = table->GetSizes();
    const std::vector<Far::Index> &offsets = table->GetOffsets();
    const std::vector<Far::Index> &indices = table->GetControlIndices();
    const std::vector<double> &weights = table->GetWeights();
    int64_t nnz = (int64_t)(n - osd_n);
    for (int32_t o = 0; o < osd_n; ++o) nnz += sizes[o];
    spia_stencils *s = spia__stencils_alloc(n, nnz);
    if (!s) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for %lld stencil weights", (long long)nnz);
    int64_t pos = 0;
    for (int32_t v = 0; v < n; ++v) {
        s->offsets[v] = pos;
        int32_t o = osd_of[v];
        if (o < 0) {
            s->indices[pos] = v;
            s->weights[pos++] = 1.0;
            continue;
        }
        for (int k = 0; k < sizes[o]; ++k) {
            Far::Index j = indices[offsets[o] + k];
            if (j < 0 || j >= osd_n) {
                spia_stencils_free(s);
                return spia__fail(status, SPIA_ERROR_INTERNAL, v, "OpenSubdiv stencil refers to point %d, not a control vertex", (int)j);
            }
            s->indices[pos] = vertex_of[j];
            s->weights[pos++] = weights[offsets[o] + k];
        }
    }
    s->offsets[n] = pos;
    spia__stencils_canonicalize(s);
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

}  // namespace

extern "C" spia_result spia__catmark_limit_stencils(const spia_mesh *mesh, const spia_adjacency *adj,
                                                    const spia_options *options, spia_stencils **out,
                                                    spia_status *status) {
    *out = nullptr;
    try {
        return build(mesh, adj, options, out, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing Catmull-Clark limit stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing Catmull-Clark limit stencils");
    }
}
