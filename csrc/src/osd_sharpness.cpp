// SPDX-License-Identifier: GPL-3.0-or-later
// Steps 1 to 4 of the OpenSubdiv path (see osd.h): Blender's sharpness
// values from the mesh's creases (or, for Loop, OpenSubdiv's), the
// renumbering that leaves out vertices no face uses, and OpenSubdiv's
// refiner for them, with the non-manifold vertices that OpenSubdiv after
// 3.6.0 sharpens; spia_sharpness's values.

#include "osd.h"

namespace spia_osd {

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
}  // namespace

// True when a and b are consecutive corners of some face.
static bool is_face_edge(const spia_mesh *m, const spia_adjacency *adj, int32_t a, int32_t b) {
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
static bool merge_repeated_creases(int32_t n, std::vector<int64_t> &first, std::vector<int32_t> &other,
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
static bool on_nonmanifold_crease(const Far::TopologyLevel &base, Far::Index v) {
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
static std::vector<int32_t> sharpened_after_360(const Far::TopologyLevel &base) {
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

// Step 1: the vertices used by faces, renumbered densely in vertex order
// (osd_of: -1 for the others), and the faces' corners in that numbering
// (remapped, left empty when no vertex is left out).
static void renumber(const spia_mesh *m, const spia_adjacency *adj, std::vector<int32_t> &osd_of,
                     std::vector<int32_t> &vertex_of, std::vector<int32_t> &remapped) {
    const int32_t n = m->vertex_count;
    osd_of.assign(n, -1);
    vertex_of.reserve(n);
    for (int32_t v = 0; v < n; ++v) {
        if (adj->first[v + 1] > adj->first[v]) {
            osd_of[v] = (int32_t)vertex_of.size();
            vertex_of.push_back(v);
        }
    }
    if ((int32_t)vertex_of.size() != n) {
        remapped.resize((size_t)adj->corner_count);
        for (int64_t c = 0; c < adj->corner_count; ++c) remapped[c] = osd_of[m->face_vertices[c]];
    }
}

// The crease pairs and weights for OpenSubdiv made again from the merged
// lists (merge_repeated_creases), each edge once, from its smaller end.
static void crease_pairs_again(int32_t n, const std::vector<int64_t> &crease_first, const std::vector<int32_t> &osd_of,
                               const Prepared &p, std::vector<int32_t> &crease_pairs,
                               std::vector<float> &crease_weights) {
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

// Blender's two-edge rule: vertex v's sharpness s with the smaller
// sharpness of its two edges added, capped at 10, where it has exactly two
// distinct neighbours along face edges; s itself otherwise.
static float with_two_edge_rule(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                                const std::vector<int64_t> &crease_first, int32_t v, float s) {
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
    return s;
}

// Blender's boundary and creasing options.
static Sdc::Options blender_options(const spia_options *opt) {
    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS
                                        ? Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER
                                        : Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    sdc.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    sdc.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);
    return sdc;
}

spia_result prepare_sharpness(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
                              bool two_edge_rule) {
    const int32_t n = m->vertex_count;
    const bool use_creases = !opt->ignore_creases;
    // Blender's own rules (loose-edge ends, the two-edge rule, smooth corners
    // off the limit) apply to Catmull-Clark, which Blender evaluates; Loop
    // follows OpenSubdiv alone and is evaluated at the exact limit.
    const bool blender = opt->scheme == SPIA_SCHEME_CATMULL_CLARK;
    const Sdc::SchemeType scheme = blender ? Sdc::SCHEME_CATMARK : Sdc::SCHEME_LOOP;

    // 1. Vertices used by faces, renumbered densely in vertex order.
    std::vector<int32_t> osd_of, vertex_of, remapped;
    renumber(m, adj, osd_of, vertex_of, remapped);
    const int32_t osd_n = (int32_t)vertex_of.size();

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
    if (!crease_first.empty() && merge_repeated_creases(n, crease_first, p.crease_other, p.crease_sharpness))
        crease_pairs_again(n, crease_first, osd_of, p, crease_pairs, crease_weights);
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
            if (blender && two_edge_rule && any_edge_crease && crease_first[v + 1] > crease_first[v])
                s = with_two_edge_rule(m, adj, p, crease_first, v, s);
        }
        if (s > 0.0f) {
            corner_indices.push_back(o);
            corner_weights.push_back(s);
        }
        p.vertex_sharpness[(size_t)v] = s;
    }

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
    p.sdc = blender_options(opt);
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

// spia_sharpness: prepare_sharpness's values in the mesh's own numbering,
// the creased face edges sorted by their (smaller, larger) end.
static spia_result sharpness(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, bool two_edge_rule,
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

}  // namespace spia_osd

extern "C" spia_result spia__osd_sharpness(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                           int two_edge_rule, int32_t *count, int32_t *pairs, float *edge_sharpness,
                                           float *vertex_sharpness, spia_status *status) {
    try {
        return spia_osd::sharpness(mesh, adj, options, two_edge_rule != 0, count, pairs, edge_sharpness, vertex_sharpness,
                         status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory reading the creases");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure reading the creases");
    }
}
