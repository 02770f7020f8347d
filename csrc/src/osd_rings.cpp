// SPDX-License-Identifier: GPL-3.0-or-later
// Rows from a vertex's one ring, with Sdc's masks and no mesh refined:
// semi-sharp vertices of manifold fans (6a, 6b: the ring read from the
// mesh, the limit mask carried back level by level) and non-manifold
// vertices taken from their crease (6c).

#include "osd.h"

namespace spia_osd {

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

namespace {
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
}  // namespace

// The limit mask at a ring's last level into g (centre, edge ends, far
// corners), semi-sharpness left taken as smooth (es is changed so); false
// at a dart or where the mask is not of the kind expected.
static bool last_limit_mask(const Sdc::Scheme<Sdc::SCHEME_CATMARK> &scheme, const Sdc::Crease &crease, int n, int nf,
                            std::vector<float> &es, float vs, int levels, std::vector<double> &g) {
    for (float &x : es)
        if (x < kInfiniteSharpness) x = 0.0f;
    if (vs < kInfiniteSharpness) vs = 0.0f;
    RingVertex vertex{n, nf, vs, es.data()};
    RingMask mask(g.data(), g.data() + 1, g.data() + 1 + n);
    const Sdc::Crease::Rule rule = crease.DetermineVertexVertexRule(vs, n, es.data());
    if (rule == Sdc::Crease::RULE_DART || levels == 0) return false;
    scheme.ComputeVertexLimitMask(vertex, mask, rule);
    if (mask.nv != 1 || (mask.ne != 0 && mask.ne != n) || (mask.nf != 0 && (mask.nf != nf || mask.centres)))
        return false;
    if (mask.ne == 0) std::fill(g.begin() + 1, g.begin() + 1 + n, 0.0);
    if (mask.nf == 0) std::fill(g.begin() + 1 + n, g.end(), 0.0);
    return true;
}

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
    if (!last_limit_mask(scheme, crease, n, nf, es, vs, levels, s.g)) return false;
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
static bool span_ends(const Far::TopologyLevel &base, Far::Index v, Far::Index ends[2]) {
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

static bool nonmanifold_row(const Far::TopologyLevel &base, Far::Index v, int levels, const Sdc::Options &sdc,
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

}  // namespace spia_osd
