// SPDX-License-Identifier: GPL-3.0-or-later
// Parts of the mesh with OpenSubdiv refiners of their own: the faces within
// two rings of given vertices, their sharpness and numbering, and the order
// the refiner takes their faces in where the mesh's scatters them.

#include "osd.h"

namespace spia_osd {

// A part of at least this many faces is taken in spatial order when its
// faces, in the mesh's order, are on average this far apart (against the
// diagonal): part_face_order.
const int32_t kScatteredPartFaces = 4096;
const double kScatteredStep = 0.05;

// The sharpness of a part of the mesh, in a numbering of its own (local_of:
// osd vertex -> local vertex, -1 outside): the creased edges the part's
// faces have (OpenSubdiv warns about others) and the sharp vertices in it.
static void restrict_sharpness(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
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
static std::vector<int32_t> part_face_order(const spia_mesh *m, const spia_adjacency *adj, const std::vector<char> &in_part,
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

}  // namespace spia_osd
