// SPDX-License-Identifier: GPL-3.0-or-later
// Step 5: how each vertex that needs OpenSubdiv is evaluated (Bfr at one of
// its corners, at the default or the isolation level; the adaptive patches
// of step 7; the crease rows of step 6c), and the corners Bfr evaluates at.

#include "osd.h"

namespace spia_osd {

// Whether a vertex of one of the faces around vertex v has more than 12
// faces.
static bool next_to_high_valence(const Far::TopologyLevel &base, Far::Index v) {
    Far::ConstIndexArray vf = base.GetVertexFaces(v);
    for (int k = 0; k < vf.size(); ++k) {
        Far::ConstIndexArray fv = base.GetFaceVertices(vf[k]);
        for (int j = 0; j < fv.size(); ++j)
            if (base.GetVertexFaces(fv[j]).size() > 12) return true;
    }
    return false;
}

// The corner at which Bfr evaluates a smooth vertex: its corner of its
// first face, or of the first face with no non-manifold vertex, since
// Bfr's irregular patch builder in OpenSubdiv 3.5 writes out of bounds on
// some faces next to non-manifold vertices (seen on the Stanford dragon
// scan).  The limit point of a smooth vertex is the same from every face.
// Whether mesh face f is such a face.
static bool is_clean_face(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const Part &part,
                          int32_t f) {
    const Far::TopologyLevel &base = part.refiner->GetLevel(0);
    for (int64_t d = adj->corner_start[f]; d < adj->corner_start[f + 1]; ++d)
        if (base.IsVertexNonManifold(part.vertex(p.osd_of[m->face_vertices[d]]))) return false;
    return true;
}

// Step 5's last part, for the vertices `approx` marks (Bfr at the
// isolation level) and those at Bfr's default levels.
static void share_level_faces(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const Part &part,
                              const std::vector<int32_t> &wanted, const std::vector<char> &approx, Evaluation &ev) {
    auto clean_face = [&](int32_t f) { return is_clean_face(m, adj, p, part, f); };
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
    auto clean_face = [&](int32_t f) { return is_clean_face(m, adj, p, part, f); };
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
    share_level_faces(m, adj, p, part, wanted, approx, ev);
}

}  // namespace spia_osd
