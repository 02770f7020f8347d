// SPDX-License-Identifier: GPL-3.0-or-later
// Uniform refinement through OpenSubdiv: Loop's limit surface for previews
// (spia__osd_refine_limit) and the Catmull-Clark subdivision of the cage
// with its creases carried down (spia__osd_subdivide).

#include "osd.h"

namespace spia_osd {

// A point for Far::PrimvarRefiner.

namespace {
struct Point {
    double p[3];
    void Clear(void * = nullptr) { p[0] = p[1] = p[2] = 0.0; }
    void AddWithWeight(const Point &src, float w) {
        for (int a = 0; a < 3; ++a) p[a] += (double)w * src.p[a];
    }
};
}  // namespace

// Refines prepare()'s refiner uniformly to `levels` and carries the
// control points down with Far::PrimvarRefiner (to the last level's limit
// positions with `limit`).  The counts, counted in closed form, are checked
// against the refinement (ne < 0: not checked).  *last_points: the last
// level's points, in OpenSubdiv's order, inside `src` or `limit_points`.
static spia_result refine_points(const spia_mesh *m, Prepared &p, int32_t levels, bool limit, int64_t nv, int64_t ne,
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
static int32_t refined_index(const Prepared &p, int32_t n, int32_t i) { return i < p.osd_n ? p.vertex_of[i] : n + (i - p.osd_n); }

// Writes the last level's points (the caller's vertices that OpenSubdiv
// did not take, loose ones, where they are) and its faces, each of
// face_size corners.
static spia_result write_refined(const spia_mesh *m, const Prepared &p, const Far::TopologyLevel &last, const Point *points,
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
static spia_result refined_total(const spia_mesh *m, const Prepared &p, int32_t levels, int64_t nv, int64_t nf,
                                 int64_t longest, int32_t *vertex_count, spia_status *status) {
    const int64_t total = m->vertex_count + (nv - p.osd_n);
    if (total > INT32_MAX || longest > INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1, "%d levels make %lld faces, too many", (int)levels,
                          (long long)nf);
    *vertex_count = (int32_t)total;
    return SPIA_OK;
}

static spia_result refine(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t levels,
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
static spia_result subdivide(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t levels,
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

}  // namespace spia_osd

extern "C" spia_result spia__osd_refine_limit(const spia_mesh *mesh, const spia_adjacency *adj,
                                              const spia_options *options, int32_t levels, int32_t *vertex_count,
                                              int32_t *face_count, float *positions, int32_t *faces,
                                              spia__refine_clock *clock, spia_status *status) {
    try {
        return spia_osd::refine(mesh, adj, options, levels, vertex_count, face_count, positions, faces, clock, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory refining the surface");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure refining the surface");
    }
}

extern "C" spia_result spia__osd_subdivide(const spia_mesh *mesh, const spia_adjacency *adj, const spia_options *options,
                                           int32_t levels, int32_t *vertex_count, int32_t *face_count,
                                           int32_t *edge_count, float *positions, int32_t *face_vertices,
                                           int32_t *edges, float *edge_creases, float *vertex_creases,
                                           spia__refine_clock *clock, spia_status *status) {
    try {
        return spia_osd::subdivide(mesh, adj, options, levels, vertex_count, face_count, edge_count, positions, face_vertices,
                         edges, edge_creases, vertex_creases, clock, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory subdividing the cage");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure subdividing the cage");
    }
}
