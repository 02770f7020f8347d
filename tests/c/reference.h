// SPDX-License-Identifier: GPL-3.0-or-later
// The oracle's core, shared by test_reference.cpp and test_shapes.cpp:
// OpenSubdiv's full adaptive limit stencils, computed the way Blender's
// Subdivision Surface modifier sets OpenSubdiv up (every face adaptively
// isolated at `quality`, infinitely sharp patches, limit at the vertex's
// corner of its first face), independently of the library's own code.
#ifndef SPIA_TEST_REFERENCE_H
#define SPIA_TEST_REFERENCE_H

#include "support.h"

#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

using namespace OpenSubdiv;

typedef std::vector<std::map<int, double>> Rows;

// OpenSubdiv after 3.6.0 (3.7.0, in Blender 5.1 and later) makes infinitely
// sharp a vertex that 3.6.0 takes for one on a non-manifold crease (two
// non-manifold edges, no boundary edge, more faces than edges) unless the
// two edges have as many faces, every other edge has two, and the faces
// around the vertex fall into fans, joined across manifold edges, each of
// which ends once on each of the two edges.  Worked out here from the face
// list alone, the fans as connected components (OpenSubdiv and the library
// walk the faces in the refiner's order instead).  An edge is non-manifold
// as OpenSubdiv counts it: more than two faces, or two that run it the same
// way.  fv is in reference numbering, n vertices.
static std::vector<bool> off_nonmanifold_creases(int n, int nf, const int *sizes, const std::vector<int> &fv) {
    struct Use {
        int prev, next;  // the face's neighbours of the vertex
    };
    std::vector<std::vector<Use>> uses(n);
    std::map<std::pair<int, int>, std::vector<int>> runs;  // edge -> +1 (low to high) or -1 per face
    int64_t c = 0;
    for (int f = 0; f < nf; ++f) {
        const int k = sizes[f];
        for (int i = 0; i < k; ++i) {
            const int a = fv[c + i], b = fv[c + (i + 1) % k], z = fv[c + (i + k - 1) % k];
            uses[a].push_back(Use{z, b});
            runs[std::make_pair(std::min(a, b), std::max(a, b))].push_back(a < b ? 1 : -1);
        }
        c += k;
    }
    auto edge_runs = [&](int a, int b) -> const std::vector<int> & {
        return runs[std::make_pair(std::min(a, b), std::max(a, b))];
    };
    auto non_manifold = [&](int a, int b) {
        const std::vector<int> &r = edge_runs(a, b);
        return r.size() > 2 || (r.size() == 2 && r[0] == r[1]);
    };
    std::vector<bool> out(n, false);
    for (int v = 0; v < n; ++v) {
        std::set<int> neighbours;
        for (const Use &u : uses[v]) {
            neighbours.insert(u.prev);
            neighbours.insert(u.next);
        }
        std::vector<int> crease;
        int boundary = 0;
        bool others_two = true;
        for (int w : neighbours) {
            const size_t faces = edge_runs(v, w).size();
            if (non_manifold(v, w)) crease.push_back(w);
            else if (faces != 2) others_two = false;
            boundary += faces == 1;
        }
        if (crease.size() != 2 || boundary != 0 || uses[v].size() <= neighbours.size()) continue;
        bool on_crease = others_two && edge_runs(v, crease[0]).size() == edge_runs(v, crease[1]).size();
        // Fans: face uses joined where they share a manifold edge.
        const int k = (int)uses[v].size();
        std::vector<int> root(k);
        for (int i = 0; i < k; ++i) root[i] = i;
        std::function<int(int)> find = [&](int i) { return root[i] == i ? i : root[i] = find(root[i]); };
        for (int i = 0; i < k; ++i)
            for (int j = i + 1; j < k; ++j)
                for (int w : {uses[v][i].prev, uses[v][i].next})
                    if ((w == uses[v][j].prev || w == uses[v][j].next) && !non_manifold(v, w)) root[find(i)] = find(j);
        std::map<int, std::pair<int, int>> ends;  // fan -> times it meets each crease edge
        for (int i = 0; i < k; ++i)
            for (int w : {uses[v][i].prev, uses[v][i].next}) {
                ends[find(i)].first += w == crease[0];
                ends[find(i)].second += w == crease[1];
            }
        for (const auto &kv : ends) on_crease = on_crease && kv.second.first == 1 && kv.second.second == 1;
        out[v] = !on_crease;
    }
    return out;
}

// osd_version: spia_options.opensubdiv_version.  With per_edge > 0: the
// rows of the samples inside the faces instead (spia_surface_stencils_create's
// layout), from the factory at every ptex face.
// The vertices faces use, renumbered densely in order (used: mesh ->
// reference numbering, -1 for the others; back: the inverse), and the
// faces in that numbering.
static void renumber_used(const tmesh &m, std::vector<int> &used, std::vector<int> &back, std::vector<int> &fv) {
    used.assign((size_t)m.nv, -1);
    back.clear();
    for (int64_t c = 0; c < m.nfv; ++c) used[m.fv[c]] = 1;
    for (int v = 0; v < m.nv; ++v)
        if (used[v] > 0) {
            used[v] = (int)back.size();
            back.push_back(v);
        }
    fv.assign(m.fv, m.fv + m.nfv);
    for (int &v : fv) v = used[v];
}

// OpenSubdiv's refiner of m's faces (fv in reference numbering, n
// vertices) with these creases and corners, as the library sets it up.
static Far::TopologyRefiner *refiner_of(const tmesh &m, int n, const std::vector<int> &fv,
                                        const std::vector<int> &pairs, const std::vector<float> &pair_w,
                                        const std::vector<int> &corners, const std::vector<float> &corner_w,
                                        bool preserve_corners, Sdc::SchemeType scheme) {
    Far::TopologyDescriptor d;
    d.numVertices = n;
    d.numFaces = m.nf;
    d.numVertsPerFace = m.sizes;
    d.vertIndicesPerFace = fv.data();
    d.numCreases = (int)pair_w.size();
    d.creaseVertexIndexPairs = pairs.data();
    d.creaseWeights = pair_w.data();
    d.numCorners = (int)corner_w.size();
    d.cornerVertexIndices = corners.data();
    d.cornerWeights = corner_w.data();
    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(preserve_corners ? Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER
                                                     : Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    sdc.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    typedef Far::TopologyRefinerFactory<Far::TopologyDescriptor> F;
    return F::Create(d, F::Options(scheme, sdc));
}

static Rows reference_rows(const tmesh &m, int quality, bool preserve_corners, bool use_creases, int osd_version = 0,
                           int per_edge = 0) {
    std::vector<int> used, back, fv;
    renumber_used(m, used, back, fv);
    std::set<std::pair<int, int>> face_edges;
    std::vector<std::set<int>> neighbours(back.size());
    int64_t c = 0;
    for (int f = 0; f < m.nf; ++f) {
        for (int k = 0; k < m.sizes[f]; ++k) {
            int a = fv[c + k], b = fv[c + (k + 1) % m.sizes[f]];
            face_edges.insert(std::make_pair(std::min(a, b), std::max(a, b)));
            neighbours[a].insert(b);
            neighbours[b].insert(a);
        }
        c += m.sizes[f];
    }
    std::vector<float> vsharp(back.size(), 0.0f);
    std::vector<bool> infinite(back.size(), false);
    std::map<std::pair<int, int>, float> esharp;
    for (int e = 0; e < m.ne; ++e) {
        int a = used[m.edges[2 * e]], b = used[m.edges[2 * e + 1]];
        if (a < 0 || b < 0 || !face_edges.count(std::make_pair(std::min(a, b), std::max(a, b)))) {
            if (a >= 0) infinite[a] = true;
            if (b >= 0) infinite[b] = true;
            continue;
        }
        float cr = m.edge_creases ? m.edge_creases[e] : 0.0f;
        float s = use_creases ? cr * cr * 10.0f : 0.0f;
        if (s >= 1e-6f) esharp[std::make_pair(std::min(a, b), std::max(a, b))] = s;
    }
    std::vector<int> pairs, corners;
    std::vector<float> pair_w, corner_w;
    for (auto &kv : esharp) {
        pairs.push_back(kv.first.first);
        pairs.push_back(kv.first.second);
        pair_w.push_back(kv.second);
    }
    for (size_t o = 0; o < back.size(); ++o) {
        float s = 0.0f;
        if (infinite[o]) {
            s = 10.0f;
        } else {
            float cr = (use_creases && m.vertex_creases) ? m.vertex_creases[back[o]] : 0.0f;
            s = cr * cr * 10.0f;
            if (neighbours[o].size() == 2) {
                float e[2];
                int k = 0;
                for (int w : neighbours[o]) {
                    auto it = esharp.find(std::make_pair(std::min((int)o, w), std::max((int)o, w)));
                    e[k++] = it == esharp.end() ? 0.0f : it->second;
                }
                s = std::min(s + std::min(e[0], e[1]), 10.0f);
            }
        }
        if (s > 0.0f) {
            corners.push_back((int)o);
            corner_w.push_back(s);
        }
    }
    if (osd_version > 30600) {
        std::vector<bool> sharpen = off_nonmanifold_creases((int)back.size(), m.nf, m.sizes, fv);
        for (size_t o = 0; o < back.size(); ++o) {
            if (!sharpen[o]) continue;
            auto at = std::find(corners.begin(), corners.end(), (int)o);
            if (at == corners.end()) {
                corners.push_back((int)o);
                corner_w.push_back(10.0f);
            } else {
                corner_w[at - corners.begin()] = 10.0f;
            }
        }
    }
    std::unique_ptr<Far::TopologyRefiner> r(
        refiner_of(m, (int)back.size(), fv, pairs, pair_w, corners, corner_w, preserve_corners, Sdc::SCHEME_CATMARK));
    Far::TopologyRefiner::AdaptiveOptions ao(quality);
    ao.useInfSharpPatch = true;
    r->RefineAdaptive(ao);
    Far::PtexIndices ptex(*r);
    if (per_edge > 0) {
        const int per = per_edge * per_edge;
        std::vector<double> gs(per), gt(per);
        for (int j = 0; j < per_edge; ++j)
            for (int i = 0; i < per_edge; ++i) gs[j * per_edge + i] = (i + 0.5) / per_edge, gt[j * per_edge + i] = (j + 0.5) / per_edge;
        Far::LimitStencilTableFactoryReal<double>::LocationArrayVec locs(ptex.GetNumFaces());
        for (int f = 0; f < ptex.GetNumFaces(); ++f) {
            locs[f].ptexIdx = f;
            locs[f].numLocations = per;
            locs[f].s = gs.data();
            locs[f].t = gt.data();
        }
        Far::LimitStencilTableFactoryReal<double>::Options lo;
        lo.generate1stDerivatives = false;
        std::unique_ptr<const Far::LimitStencilTableReal<double>> t(
            Far::LimitStencilTableFactoryReal<double>::Create(*r, locs, nullptr, nullptr, lo));
        Rows rows((size_t)ptex.GetNumFaces() * per);
        for (size_t i = 0; i < rows.size(); ++i) {
            auto st = t->GetLimitStencil((Far::Index)i);
            for (int k = 0; k < st.GetSize(); ++k) rows[i][back[st.GetVertexIndices()[k]]] += st.GetWeights()[k];
        }
        return rows;
    }
    static const double S[4] = {0, 1, 1, 0}, T[4] = {0, 0, 1, 1};
    Far::LimitStencilTableFactoryReal<double>::LocationArrayVec locs(back.size());
    std::vector<bool> done(back.size(), false);
    c = 0;
    for (int f = 0; f < m.nf; ++f) {
        for (int k = 0; k < m.sizes[f]; ++k) {
            int o = fv[c + k];
            if (done[o]) continue;
            done[o] = true;
            auto &l = locs[o];
            l.numLocations = 1;
            bool quad = m.sizes[f] == 4;
            l.ptexIdx = ptex.GetFaceId(f) + (quad ? 0 : k);
            l.s = quad ? &S[k] : &S[0];
            l.t = quad ? &T[k] : &T[0];
        }
        c += m.sizes[f];
    }
    Far::LimitStencilTableFactoryReal<double>::Options lo;
    lo.generate1stDerivatives = false;
    std::unique_ptr<const Far::LimitStencilTableReal<double>> t(
        Far::LimitStencilTableFactoryReal<double>::Create(*r, locs, nullptr, nullptr, lo));
    // Vertices no face uses stay put, but one with exactly two (loose) edges
    // goes to (prev + 4 V + next) / 6, as Blender's modifier puts it.
    Rows rows(m.nv);
    std::vector<std::vector<int>> loose(m.nv);
    for (int e = 0; e < m.ne; ++e) {
        loose[m.edges[2 * e]].push_back(m.edges[2 * e + 1]);
        loose[m.edges[2 * e + 1]].push_back(m.edges[2 * e]);
    }
    for (int v = 0; v < m.nv; ++v) {
        if (used[v] >= 0) continue;
        rows[v][v] = loose[v].size() == 2 ? 4.0 / 6.0 : 1.0;
        if (loose[v].size() == 2)
            for (int w : loose[v]) rows[v][w] += 1.0 / 6.0;
    }
    for (size_t o = 0; o < back.size(); ++o) {
        auto st = t->GetLimitStencil((Far::Index)o);
        for (int k = 0; k < st.GetSize(); ++k) rows[back[o]][back[st.GetVertexIndices()[k]]] += st.GetWeights()[k];
    }
    return rows;
}

// Loop's exact limit stencils the plain way: the whole mesh refined
// uniformly until every semi-sharp feature has decayed (ceil of the largest
// finite sharpness levels, at least one, at most ten), then OpenSubdiv's
// limit masks, carried as sparse stencils over the control vertices in
// double.  Sharpness as OpenSubdiv takes Blender's
// creases, without Blender's own rules: 10 c^2 on face edges (an edge
// listed twice takes its larger), vertex creases alone; vertices no face
// uses keep their position.  Returns false, leaving rows empty, when the
// last level would have more than max_faces faces (four times the faces a
// level).
struct LoopStencil {
    std::vector<std::pair<int, double>> w;
    void Clear(void * = nullptr) { w.clear(); }
    void AddWithWeight(const LoopStencil &src, double weight) {
        for (const auto &e : src.w) w.emplace_back(e.first, weight * e.second);
    }
    void Merge() {
        std::sort(w.begin(), w.end());
        size_t out = 0;
        for (size_t i = 0; i < w.size();) {
            const int j = w[i].first;
            double sum = 0.0;
            while (i < w.size() && w[i].first == j) sum += w[i++].second;
            w[out++] = std::make_pair(j, sum);
        }
        w.resize(out);
    }
};

static bool loop_uniform_rows(const tmesh &m, bool preserve_corners, bool use_creases, int64_t max_faces, Rows &rows) {
    rows.clear();
    std::vector<int> used, back, fv;
    renumber_used(m, used, back, fv);
    std::set<std::pair<int, int>> face_edges;
    for (int f = 0, c = 0; f < m.nf; c += m.sizes[f++])
        for (int k = 0; k < m.sizes[f]; ++k) {
            const int a = fv[c + k], b = fv[c + (k + 1) % m.sizes[f]];
            face_edges.insert(std::make_pair(std::min(a, b), std::max(a, b)));
        }
    std::map<std::pair<int, int>, float> esharp;
    float sharpest = 0.0f;
    for (int e = 0; e < m.ne && use_creases && m.edge_creases; ++e) {
        const int a = used[m.edges[2 * e]], b = used[m.edges[2 * e + 1]];
        const std::pair<int, int> key(std::min(a, b), std::max(a, b));
        if (a < 0 || b < 0 || !face_edges.count(key)) continue;
        const float s = m.edge_creases[e] * m.edge_creases[e] * 10.0f;
        if (s < 1e-6f) continue;
        esharp[key] = std::max(esharp[key], s);
    }
    std::vector<int> pairs, corners;
    std::vector<float> pair_w, corner_w;
    for (const auto &kv : esharp) {
        pairs.push_back(kv.first.first);
        pairs.push_back(kv.first.second);
        pair_w.push_back(kv.second);
        if (kv.second < 10.0f) sharpest = std::max(sharpest, kv.second);
    }
    for (size_t o = 0; o < back.size() && use_creases && m.vertex_creases; ++o) {
        const float c = m.vertex_creases[back[o]], s = c * c * 10.0f;
        if (s <= 0.0f) continue;
        corners.push_back((int)o);
        corner_w.push_back(s);
        if (s < 10.0f) sharpest = std::max(sharpest, s);
    }
    const int levels = std::max(1, std::min(10, (int)std::ceil(sharpest)));
    int64_t faces = m.nf;
    for (int l = 0; l < levels; ++l) faces *= 4;
    if (faces > max_faces) return false;
    std::unique_ptr<Far::TopologyRefiner> r(
        refiner_of(m, (int)back.size(), fv, pairs, pair_w, corners, corner_w, preserve_corners, Sdc::SCHEME_LOOP));
    if (!r) return false;
    Far::TopologyRefiner::UniformOptions uniform(levels);
    uniform.fullTopologyInLastLevel = true;
    r->RefineUniform(uniform);
    std::vector<LoopStencil> all((size_t)r->GetNumVerticesTotal());
    for (size_t i = 0; i < back.size(); ++i) all[i].w.emplace_back((int)i, 1.0);
    Far::PrimvarRefinerReal<double> primvar(*r);
    LoopStencil *src = all.data();
    for (int l = 1; l <= levels; ++l) {
        LoopStencil *dst = src + r->GetLevel(l - 1).GetNumVertices();
        primvar.Interpolate(l, src, dst);
        for (int i = 0; i < r->GetLevel(l).GetNumVertices(); ++i) dst[i].Merge();
        src = dst;
    }
    std::vector<LoopStencil> limit((size_t)r->GetLevel(levels).GetNumVertices());
    LoopStencil *limit_dst = limit.data();
    primvar.Limit(src, limit_dst);
    rows.assign((size_t)m.nv, std::map<int, double>());
    for (int v = 0; v < m.nv; ++v)
        if (used[v] < 0) rows[(size_t)v][v] = 1.0;
    for (size_t o = 0; o < back.size(); ++o)  // (children of vertices come first, in order)
        for (const auto &e : limit[o].w) rows[(size_t)back[o]][back[(size_t)e.first]] += e.second;
    return true;
}

#endif
