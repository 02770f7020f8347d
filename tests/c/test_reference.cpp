// The oracle: OpenSubdiv's full adaptive limit stencils, computed here the
// way Blender's Subdivision Surface modifier sets OpenSubdiv up (every face
// adaptively isolated at `quality`, infinitely sharp patches, limit at the
// vertex's corner of its first face), independently of the library's own
// code, which takes shortcuts where they are exact.  Every row must agree.
#include "support.h"

#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <algorithm>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

using namespace OpenSubdiv;

typedef std::vector<std::map<int, double>> Rows;

static Rows reference_rows(const tmesh &m, int quality, bool preserve_corners, bool use_creases) {
    std::vector<int> used(m.nv, -1), back;
    for (int64_t c = 0; c < m.nfv; ++c) used[m.fv[c]] = 1;
    for (int v = 0; v < m.nv; ++v)
        if (used[v] > 0) {
            used[v] = (int)back.size();
            back.push_back(v);
        }
    std::vector<int> fv(m.fv, m.fv + m.nfv);
    for (int &v : fv) v = used[v];
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
    Far::TopologyDescriptor d;
    d.numVertices = (int)back.size();
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
    std::unique_ptr<Far::TopologyRefiner> r(F::Create(d, F::Options(Sdc::SCHEME_CATMARK, sdc)));
    Far::TopologyRefiner::AdaptiveOptions ao(quality);
    ao.useInfSharpPatch = true;
    r->RefineAdaptive(ao);
    Far::PtexIndices ptex(*r);
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

// Creases 0.3, 0.5, 0.7 or 1.0 (sharpness 0.9, 2.5, 4.9, infinite) on a
// fraction of the face edges chosen at random, and 0.4 on a few vertices.
static void add_random_creases(tmesh *m, double fraction, uint64_t seed) {
    std::set<std::pair<int, int>> edges;
    int64_t c = 0;
    for (int f = 0; f < m->nf; ++f) {
        for (int k = 0; k < m->sizes[f]; ++k) {
            int a = m->fv[c + k], b = m->fv[c + (k + 1) % m->sizes[f]];
            edges.insert(std::make_pair(std::min(a, b), std::max(a, b)));
        }
        c += m->sizes[f];
    }
    static const float values[4] = {0.3f, 0.5f, 0.7f, 1.0f};
    auto next = [&seed]() {
        seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
        return (double)(seed >> 11) / 9007199254740992.0;
    };
    for (const auto &e : edges)
        if (next() < fraction) tmesh_edge(m, e.first, e.second, values[(int)(next() * 4) & 3]);
    for (int v = 0; v < m->nv; ++v)
        if (next() < 0.02) tmesh_vertex_crease(m, v, 0.4f);
}

static void compare(const tmesh &m, const std::string &name, int quality, bool preserve, bool creases) {
    Rows ref = reference_rows(m, quality, preserve, creases);
    spia_mesh mesh = tmesh_view(&m);
    spia_options o = spia_options_default();
    o.quality = quality;
    o.boundary_smooth = preserve ? SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS : SPIA_BOUNDARY_SMOOTH_ALL;
    o.ignore_creases = creases ? 0 : 1;
    spia_stencils *s = nullptr;
    spia_status st;
    spia_result res = spia_limit_stencils_create(&mesh, &o, &s, &st);
    CHECK(res == SPIA_OK, "%s: %s", name.c_str(), st.message);
    if (res != SPIA_OK) return;
    std::vector<int64_t> off(m.nv + 1);
    std::vector<int32_t> idx(spia_stencils_weight_count(s));
    std::vector<double> w(idx.size());
    spia_stencils_copy_csr(s, off.data(), idx.data(), w.data());
    double worst = 0.0;
    int worst_v = -1;
    for (int v = 0; v < m.nv; ++v) {
        std::map<int, double> row;
        for (int64_t k = off[v]; k < off[v + 1]; ++k) {
            CHECK(k == off[v] || idx[k] > idx[k - 1], "%s: row %d not sorted", name.c_str(), v);
            row[idx[k]] += w[k];
        }
        for (auto &kv : ref[v]) row[kv.first] -= kv.second;
        for (auto &kv : row)
            if (std::fabs(kv.second) > worst) {
                worst = std::fabs(kv.second);
                worst_v = v;
            }
    }
    CHECK(worst < 1e-12, "%s q=%d preserve=%d creases=%d: off by %g at vertex %d", name.c_str(), quality, (int)preserve,
          (int)creases, worst, worst_v);
    spia_stencils_free(s);
}

static void compare_all(const tmesh &m, const std::string &name, std::initializer_list<int> qualities) {
    for (int q : qualities)
        for (int preserve = 0; preserve < 2; ++preserve)
            for (int creases = 0; creases < 2; ++creases) compare(m, name, q, preserve != 0, creases != 0);
    printf("%-40s matches OpenSubdiv's full adaptive stencils\n", name.c_str());
}

int main() {
    // Semi-sharp edge creases 0.3, 0.5, 0.9, 1.0 along a line, a dart, a
    // vertex crease, and a corner crease through the two-edge rule.
    tmesh g = make_grid(8, 6);
    tmesh_edge(&g, 10, 11, 0.3f);
    tmesh_edge(&g, 11, 12, 0.5f);
    tmesh_edge(&g, 12, 13, 0.9f);
    tmesh_edge(&g, 13, 14, 1.0f);
    tmesh_edge(&g, 30, 31, 0.7f);  // a dart: one creased edge ending inside
    tmesh_edge(&g, 0, 1, 0.6f);    // boundary edge at a corner
    tmesh_edge(&g, 0, 9, 0.8f);
    tmesh_vertex_crease(&g, 40, 0.6f);
    tmesh_vertex_crease(&g, 8, 0.4f);  // a corner
    compare_all(g, "creased grid", {1, 2, 3, 6, 10});

    // Loose vertices and a loose edge attached to the surface.
    int32_t lone = tmesh_vertex(&g, 3, 3, 3);
    int32_t tip = tmesh_vertex(&g, 4, 4, 4);
    tmesh_edge(&g, 20, tip, 0.0f);
    tmesh_edge(&g, lone, tip, 0.0f);
    compare_all(g, "creased grid + loose parts", {3});
    tmesh_free(&g);

    // A non-manifold fin: a third face on an interior edge.
    tmesh fin = make_grid(4, 4);
    int32_t p = tmesh_vertex(&fin, 2, 1.5, 1), q = tmesh_vertex(&fin, 2, 2.5, 1);
    tmesh_quad(&fin, 7, 12, q, p);  // vertices 7 and 12 share an interior grid edge
    compare_all(fin, "grid with a non-manifold fin", {1, 3, 6});
    tmesh_free(&fin);

    // Strips of two quads apart from each other: four smooth corners each,
    // 480 adaptive rows in all, more than one batch of sub-meshes.
    tmesh strips;
    memset(&strips, 0, sizeof strips);
    for (int k = 0; k < 120; ++k) {
        int32_t v[6];
        for (int i = 0; i < 6; ++i) v[i] = tmesh_vertex(&strips, 3.0 * k + (i % 3), i / 3, 0.1 * ((k * 7 + i) % 5));
        tmesh_quad(&strips, v[0], v[1], v[4], v[3]);
        tmesh_quad(&strips, v[1], v[2], v[5], v[4]);
    }
    compare_all(strips, "120 separate two-quad strips", {1, 3});
    tmesh_free(&strips);

    tmesh t = make_torus(9, 6, 1);
    compare_all(t, "triangulated torus", {1, 3});
    tmesh_free(&t);

    static const char *names[] = {"mushroom.obj", "double-torus.obj", "teapot.obj", "catmark_car.obj",
                                  "catmark_nonman_edges.obj", "bunny.obj"};
    for (const char *n : names) {
        tmesh d;
        std::string path = std::string(SPIA_TEST_DATA_DIR) + "/" + n;
        CHECK(read_obj(path.c_str(), &d), "cannot read %s", path.c_str());
        drop_degenerate_faces(&d);
        compare_all(d, n, {1, 3});
        tmesh_free(&d);
    }
    // Random semi-sharp and infinitely sharp creases (a tenth of the edges,
    // fixed seed) and vertex creases on meshes with extraordinary vertices,
    // boundaries, triangles and n-gons: the creased vertices go through Bfr
    // at the isolation level, which must build Blender's patches.
    static const char *creased[] = {"bunny.obj", "teapot.obj", "mushroom.obj", "double-torus.obj", "catmark_car.obj"};
    for (const char *n : creased) {
        tmesh d;
        std::string path = std::string(SPIA_TEST_DATA_DIR) + "/" + n;
        CHECK(read_obj(path.c_str(), &d), "cannot read %s", path.c_str());
        drop_degenerate_faces(&d);
        add_random_creases(&d, 0.1, 2024);
        compare_all(d, std::string(n) + " with random creases", {1, 2, 3, 5});
        tmesh_free(&d);
    }
    TEST_MAIN_END();
}
