// SPDX-License-Identifier: GPL-3.0-or-later
// Step 7: the vertices taken from Blender's adaptive patches, in batches of
// nearby vertices, each with a sub-mesh of its own, on the threads; each
// row is carried down the refinement levels to the control vertices.

#include "osd.h"

namespace spia_osd {

typedef Far::LimitStencilTableFactoryReal<double> LimitFactory;

// Feature vertices per adaptive sub-mesh, and the most sub-meshes.
const int32_t kFeatureBatch = 250, kMaxFeatureBatches = 64;

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

namespace {
struct FeatureBatch {
    int32_t first, count, level;  // features[first .. first + count - 1], all of one level
};
}  // namespace

// One level down: the entries of row with indices in [begin, end) replaced
// by those points' stencils in `step` (over the level below, whose points
// start at `below`), the others kept; then merged, zero sums dropped.
template <class I>
static void carry_down(std::vector<std::pair<I, double>> &row, const std::vector<SparseStencil> &step, I begin, I end,
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

// Orders osd vertices along a Morton curve through their positions (ties
// by index), so that batches of consecutive ones are close together and
// share their sub-meshes whatever the mesh's vertex order.
static void spatial_order(const spia_mesh *m, const Prepared &p, std::vector<int32_t> &list) {
    const std::vector<int32_t> order = morton_order((int32_t)list.size(), [&](int32_t i) {
        return m->positions + 3 * (int64_t)p.vertex_of[(size_t)list[(size_t)i]];
    });
    std::vector<int32_t> sorted(list.size());
    for (size_t i = 0; i < list.size(); ++i) sorted[i] = list[(size_t)order[i]];
    list.swap(sorted);
}

// The adaptive vertices by level, spatially ordered within one, and their
// batches.
static void feature_batches(const spia_mesh *m, const Prepared &p, const Evaluation &ev, std::vector<int32_t> &features,
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

// Each marked vertex's limit location: its corner of its first face, in
// the sub-mesh's ptex faces.
static void corner_locations(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, const Part &sub,
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
static void level_steps(Far::TopologyRefiner &sr, std::vector<int64_t> &level_start,
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
static bool patch_rows(const Prepared &p, const Part &sub, const std::vector<int32_t> &marked,
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
static void adaptive_batch(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, Prepared &p,
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

}  // namespace spia_osd
