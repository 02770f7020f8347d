// SPDX-License-Identifier: GPL-3.0-or-later
// Loop's rows at the exact limit: each vertex refined on a copy of its own
// fan until its semi-sharp features have decayed, then OpenSubdiv's limit
// mask there.

#include "osd.h"

namespace spia_osd {

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

namespace {
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
}  // namespace

// Levels until the semi-sharp features at vertex v of `level` have
// decayed (at least one, at most ten).
static int decay_levels(const Far::TopologyLevel &level, Far::Index v) {
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
static bool fan_limit_rows(const Far::TopologyRefiner &sub, const std::vector<int32_t> &marked,
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

}  // namespace spia_osd
