// SPDX-License-Identifier: GPL-3.0-or-later
// Limit stencils at samples inside the faces (for fitting and detail): Bfr
// face by face, and OpenSubdiv's adaptive patch table around the corners
// Bfr does not reproduce.

#include "osd.h"

namespace spia_osd {

// Limit stencils at samples inside the faces: per ptex face (a quad, or each
// corner's sub-quad of another polygon), samples_per_edge^2 points at the
// centres of a regular grid over (s, t), in t, then s order, on Blender's
// patches at quality.  Each face's rows come as one dense block over the
// face's control vertices.
//
// Most faces: Bfr, each face's surface from its own neighbourhood, with its
// approximation levels (sharp and smooth) at quality; irregular patches are
// shared among faces of the same topology, so this costs little more than
// evaluating the basis.  Bfr builds the same patches as Blender's adaptive
// refinement except at faces with a corner that is non-manifold, a smooth
// boundary vertex of one face, sharpened itself or meets three or more
// creased edges (there its sharpness decays within the isolation level;
// the differences measured up to 1e-3 at quality 1, 1e-8 at quality 3).
// Those faces go through OpenSubdiv's adaptive patch table as
// LimitStencilTableFactory builds it (Gregory end caps, the refined and
// local points' stencils), on the part of the mesh within two rings of
// them.  The factory's sums are reproduced term by term (the same order,
// so the same rows) without its search for each entry's place.

namespace {
struct FaceBlocks {
    std::vector<int32_t> columns;
    std::vector<double> weights;
};

struct SampleGrid {
    int per_face = 0;
    std::vector<double> s, t;
    // The centres of per_edge^2 cells, or with `corners` per_edge points on
    // each edge from 0 to 1 (at least 2).
    SampleGrid(int per_edge, bool corners) : per_face(per_edge * per_edge), s((size_t)per_face), t((size_t)per_face) {
        for (int j = 0; j < per_edge; ++j)
            for (int i = 0; i < per_edge; ++i) {
                s[(size_t)(j * per_edge + i)] = corners ? (double)i / (per_edge - 1) : (i + 0.5) / per_edge;
                t[(size_t)(j * per_edge + i)] = corners ? (double)j / (per_edge - 1) : (j + 0.5) / per_edge;
            }
    }
};
}  // namespace

// OpenSubdiv's adaptive patches on `refiner` (refined here) for the faces
// marked in `wanted`: per grid, per face of each, per ptex face its block,
// columns in the refiner's numbering.
static spia_result far_blocks(Far::TopologyRefiner &refiner, const spia_options *opt,
                              const std::vector<SampleGrid> &grids, const std::vector<char> &wanted,
                              std::vector<std::vector<std::vector<FaceBlocks>>> &out, spia_status *status) {
    Far::TopologyRefiner::AdaptiveOptions adaptive(opt->quality);
    adaptive.useInfSharpPatch = true;
    adaptive.considerFVarChannels = false;
    refiner.RefineAdaptive(adaptive);
    Far::PtexIndices ptex(refiner);
    typedef Far::StencilTableReal<double> Table;
    typedef Far::StencilTableFactoryReal<double> TableFactory;
    TableFactory::Options table_options;
    table_options.generateIntermediateLevels = true;
    table_options.generateControlVerts = true;
    table_options.generateOffsets = true;
    std::unique_ptr<const Table> refined(TableFactory::Create(refiner, table_options));
    Far::PatchTableFactory::Options patch_options;
    patch_options.SetPatchPrecision<double>();
    patch_options.includeBaseLevelIndices = true;
    patch_options.SetEndCapType(Far::PatchTableFactory::Options::ENDCAP_GREGORY_BASIS);
    patch_options.useInfSharpPatch = true;
    std::unique_ptr<const Far::PatchTable> patches(Far::PatchTableFactory::Create(refiner, patch_options));
    if (!refined || !patches)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv built no patches for the samples");
    const Table *points = refined.get();
    std::unique_ptr<const Table> appended;
    const Table *local = patches->GetLocalPointStencilTable<double>();
    if (local && refined->GetNumStencils() == refiner.GetNumVerticesTotal()) {
        appended.reset(TableFactory::AppendLocalPointStencilTable(refiner, refined.get(), local));
        if (!appended) return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv built no local point stencils");
        points = appended.get();
        refined.reset();
    }
    Far::PatchMap map(*patches);
    const Far::TopologyLevel &base = refiner.GetLevel(0);
    const int32_t n = base.GetNumVertices(), faces = base.GetNumFaces();
    std::vector<Far::ConstIndexArray> cvs;
    std::vector<double> basis;
    std::vector<int32_t> stamp((size_t)n, -1), slot((size_t)n, 0);
    out.assign(grids.size(), std::vector<std::vector<FaceBlocks>>((size_t)faces));
    int32_t stamp_id = 0;
    for (size_t g = 0; g < grids.size(); ++g) {
        const SampleGrid &grid = grids[g];
        const int per_face = grid.per_face;
        cvs.resize((size_t)per_face);
        basis.resize((size_t)per_face * 20);
        for (int32_t face = 0; face < faces; ++face) {
            if (!wanted[(size_t)face]) continue;
            const int size = base.GetFaceVertices(face).size();
            const int subs = size == 4 ? 1 : size;
            out[g][(size_t)face].resize((size_t)subs);
            for (int sub = 0; sub < subs; ++sub, ++stamp_id) {
                const int f = ptex.GetFaceId(face) + sub;
                FaceBlocks &fb = out[g][(size_t)face][(size_t)sub];
                for (int j = 0; j < per_face; ++j) {
                    const Far::PatchMap::Handle *handle = map.FindPatch(f, grid.s[(size_t)j], grid.t[(size_t)j]);
                    if (!handle)
                        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv has no patch under a sample");
                    cvs[(size_t)j] = patches->GetPatchVertices(*handle);
                    if (cvs[(size_t)j].size() > 20)
                        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "a patch of %d points", cvs[(size_t)j].size());
                    patches->EvaluateBasis<double>(*handle, grid.s[(size_t)j], grid.t[(size_t)j], &basis[(size_t)j * 20]);
                    for (int k = 0; k < cvs[(size_t)j].size(); ++k) {
                        const Far::StencilReal<double> point = points->GetStencil(cvs[(size_t)j][k]);
                        const Far::Index *idx = point.GetVertexIndices();
                        for (int e = 0; e < point.GetSize(); ++e) {
                            const Far::Index c = idx[e];
                            if (c < 0 || c >= n)
                                return spia__fail(status, SPIA_ERROR_INTERNAL, -1,
                                                  "OpenSubdiv sample stencil refers to point %d, not a control vertex",
                                                  (int)c);
                            if (stamp[(size_t)c] != stamp_id) {
                                stamp[(size_t)c] = stamp_id;
                                slot[(size_t)c] = (int32_t)fb.columns.size();
                                fb.columns.push_back(c);
                            }
                        }
                    }
                }
                const size_t width = fb.columns.size();
                fb.weights.assign(width * (size_t)per_face, 0.0);
                for (int j = 0; j < per_face; ++j) {
                    double *row = &fb.weights[(size_t)j * width];
                    for (int k = 0; k < cvs[(size_t)j].size(); ++k) {
                        const double b = basis[(size_t)j * 20 + (size_t)k];
                        if (b == 0.0) continue;
                        const Far::StencilReal<double> point = points->GetStencil(cvs[(size_t)j][k]);
                        const Far::Index *idx = point.GetVertexIndices();
                        const double *w = point.GetWeights();
                        for (int e = 0; e < point.GetSize(); ++e)
                            if (w[e] != 0.0) row[slot[(size_t)idx[e]]] += b * w[e];
                    }
                }
            }
        }
    }
    return SPIA_OK;
}

// The faces Bfr does not reproduce (see above), as a mark per mesh face.
static std::vector<char> faces_for_far(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p, bool &any) {
    const Far::TopologyLevel &base = p.refiner->GetLevel(0);
    std::vector<char> special((size_t)p.osd_n, 0), face((size_t)m->face_count, 0);
    for (int32_t o = 0; o < p.osd_n; ++o) {
        bool s = base.IsVertexNonManifold(o) || base.GetVertexSharpness(o) > 0.0f ||
                 (base.IsVertexBoundary(o) && base.GetVertexFaces(o).size() == 1);
        if (!s) {
            Far::ConstIndexArray ve = base.GetVertexEdges(o);
            int creased = 0;
            for (int k = 0; k < ve.size(); ++k) creased += base.GetEdgeSharpness(ve[k]) > 0.0f;
            s = creased >= 3;
        }
        special[(size_t)o] = s;
    }
    any = false;
    for (int32_t f = 0; f < m->face_count; ++f)
        for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c)
            if (special[(size_t)p.osd_of[m->face_vertices[c]]]) {
                face[(size_t)f] = 1;
                any = true;
                break;
            }
    return face;
}

// What a sample block consumer's nonzero return stops the blocks with.
static spia_result emit_stopped(int stop, spia_status *status) {
    if (stop == SPIA_ERROR_CANCELLED)
        return spia__fail(status, SPIA_ERROR_CANCELLED, -1, "cancelled computing the sample stencils");
    if (stop == SPIA_ERROR_INTERNAL)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "the sample stencils do not match the cage's faces");
    return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
}

namespace {
// A set of points to make blocks at (spia__block_points), and where they go.
struct PointSet {
    SampleGrid grid;
    spia__sample_block_fn emit;
    void *user;
};

// One face's blocks from Bfr: its columns (mesh numbering, each once) and,
// per set of points, the weights of each of its ptex faces in turn.
struct BfrFace {
    int subs = 0;
    std::vector<int32_t> columns;
    std::vector<std::vector<double>> weights;
};

struct BfrScratch {
    Bfr::Surface<double> srf;
    std::vector<Far::Index> cv;
    std::vector<int32_t> slot;  // per control point, its column
    std::vector<double> w;
};
}  // namespace

// Faces go to the threads kBatchFaces at a time, in pieces of kPieceFaces,
// each thread with a Bfr factory of its own, made afresh every kFactoryFaces
// faces (a cache shared between threads takes its lock for every face, and
// one kept for the whole mesh grows: see bfr_rows in osd_limit_stencils.cpp).
// The blocks are then handed to the sets' emit in face order on the calling
// thread, so what emit sees (and the progress it calls) does not depend on
// the threads.
const int32_t kBatchFaces = 8192, kPieceFaces = 512, kFactoryFaces = 131072;

// Face f's blocks for every set.  False where Bfr makes no surface.
static bool bfr_face(const Bfr::RefinerSurfaceFactory<> &factory, int32_t f, const Prepared &p,
                     const std::vector<PointSet> &sets, BfrScratch &x, BfrFace &out) {
    if (!factory.InitVertexSurface(f, &x.srf) || !x.srf.IsValid()) return false;
    const size_t points = (size_t)x.srf.GetNumControlPoints();
    x.cv.resize(points);
    x.w.resize(points);
    x.slot.resize(points);
    x.srf.GetControlPointIndices(x.cv.data());
    out.columns.clear();
    for (size_t k = 0; k < points; ++k) {
        size_t j = 0;
        while (j < out.columns.size() && out.columns[j] != x.cv[k]) ++j;
        if (j == out.columns.size()) out.columns.push_back(x.cv[k]);
        x.slot[k] = (int32_t)j;
    }
    const Bfr::Parameterization param = x.srf.GetParameterization();
    out.subs = param.HasSubFaces() ? param.GetFaceSize() : 1;
    const size_t width = out.columns.size();
    for (size_t i = 0; i < width; ++i) out.columns[i] = p.vertex_of[(size_t)out.columns[i]];
    out.weights.resize(sets.size());
    for (size_t s = 0; s < sets.size(); ++s) {
        const SampleGrid &grid = sets[s].grid;
        std::vector<double> &block = out.weights[s];
        block.assign(width * (size_t)grid.per_face * (size_t)out.subs, 0.0);
        for (int sub = 0; sub < out.subs; ++sub)
            for (int j = 0; j < grid.per_face; ++j) {
                double uv[2], st[2] = {grid.s[(size_t)j], grid.t[(size_t)j]};
                if (param.HasSubFaces())
                    param.ConvertNormalizedSubFaceToCoord(sub, st, uv);
                else
                    uv[0] = st[0], uv[1] = st[1];
                x.srf.EvaluateStencil(uv, x.w.data());
                double *row = &block[((size_t)sub * (size_t)grid.per_face + (size_t)j) * width];
                for (size_t k = 0; k < points; ++k) row[x.slot[k]] += x.w[k];
            }
    }
    return true;
}

static spia_result surface_blocks(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt,
                                  const std::vector<PointSet> &sets, spia_status *status) {
    Prepared p;
    spia_result r = prepare(m, adj, opt, p, status);
    if (r != SPIA_OK) return r;
    std::vector<SampleGrid> grids;
    for (const PointSet &set : sets) grids.push_back(set.grid);

    // The faces for OpenSubdiv's patch table, on their part of the mesh.
    bool any_far = false;
    const std::vector<char> far_face = faces_for_far(m, adj, p, any_far);
    std::vector<std::vector<std::vector<FaceBlocks>>> far_out;  // per set, per face of the part
    std::vector<int32_t> local_face_of;                         // mesh face -> face of the part
    Part part;
    if (any_far) {
        std::vector<int32_t> marked;
        for (int32_t f = 0; f < m->face_count; ++f)
            if (far_face[(size_t)f])
                for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c)
                    marked.push_back(p.osd_of[m->face_vertices[c]]);
        std::sort(marked.begin(), marked.end());
        marked.erase(std::unique(marked.begin(), marked.end()), marked.end());
        if ((r = make_part(m, adj, opt, p, two_ring_faces(m, adj, p, marked), false, nullptr, part, status)) != SPIA_OK)
            return r;
        const int32_t local_faces = part.refiner->GetLevel(0).GetNumFaces();
        std::vector<char> wanted((size_t)local_faces, 0);
        for (int32_t i = 0; i < local_faces; ++i) wanted[(size_t)i] = far_face[(size_t)part.mesh_face(i)];
        if ((r = far_blocks(*part.refiner, opt, grids, wanted, far_out, status)) != SPIA_OK) return r;
        local_face_of.assign((size_t)m->face_count, -1);
        for (int32_t i = 0; i < local_faces; ++i) local_face_of[(size_t)part.mesh_face(i)] = i;
    }

    const Far::TopologyRefiner &refiner = *p.refiner;
    Bfr::SurfaceFactory::Options qopt;
    qopt.SetApproxLevelSharp(opt->quality).SetApproxLevelSmooth(opt->quality);
    const int threads = opt->threads > 0 ? opt->threads : 1;
    std::vector<int32_t> failed_face_of((size_t)threads, INT32_MAX);  // per thread, the first face Bfr failed on
    std::vector<unsigned char> out_of_memory_of((size_t)threads, 0), other_failure_of((size_t)threads, 0);
    struct Worker {
        std::unique_ptr<Bfr::RefinerSurfaceFactory<>> factory;
        int64_t faces = 0;  // made by its factory
        BfrScratch x;
    };
    std::vector<Worker> workers((size_t)threads);
    // Two batches: one made on the threads while the one before is handed
    // over on the calling thread (thread 0, when it takes a piece of the
    // loop, first; or after it).
    std::vector<BfrFace> batches[2];
    for (auto &batch : batches) batch.resize((size_t)std::min(kBatchFaces, m->face_count));
    std::vector<int32_t> columns;
    int64_t ptex = 0;
    int32_t pending_f0 = -1, pending_count = 0, pending = 0;  // the batch made and not handed over
    // Hands the pending batch's blocks over, in face order.
    auto hand_over = [&]() -> spia_result {
        const std::vector<BfrFace> &batch = batches[pending];
        const int32_t f0 = pending_f0;
        pending_f0 = -1;
        for (int32_t i = 0; i < pending_count; ++i) {
            const int32_t f = f0 + i;
            if (any_far && far_face[(size_t)f]) {
                const int32_t local = local_face_of[(size_t)f];
                const int64_t subs = (int64_t)far_out[0][(size_t)local].size();
                for (size_t s = 0; s < sets.size(); ++s)
                    for (int64_t sub = 0; sub < subs; ++sub) {
                        const FaceBlocks &fb = far_out[s][(size_t)local][(size_t)sub];
                        columns.resize(fb.columns.size());
                        for (size_t k = 0; k < columns.size(); ++k)
                            columns[k] = p.vertex_of[(size_t)part.osd(fb.columns[k])];
                        if (int stop = sets[s].emit(sets[s].user, ptex + sub, (int32_t)columns.size(), columns.data(),
                                                    fb.weights.data()))
                            return emit_stopped(stop, status);
                    }
                ptex += subs;
                continue;
            }
            const BfrFace &face = batch[(size_t)i];
            const size_t width = face.columns.size();
            for (size_t s = 0; s < sets.size(); ++s) {
                const size_t per_sub = width * (size_t)sets[s].grid.per_face;
                for (int sub = 0; sub < face.subs; ++sub)
                    if (int stop = sets[s].emit(sets[s].user, ptex + sub, (int32_t)width, face.columns.data(),
                                                face.weights[s].data() + (size_t)sub * per_sub))
                        return emit_stopped(stop, status);
            }
            ptex += face.subs;
        }
        return SPIA_OK;
    };
    for (int32_t f0 = 0; f0 < m->face_count; f0 += kBatchFaces) {
        const int32_t count = std::min(kBatchFaces, m->face_count - f0);
        const int making = pending_f0 >= 0 ? 1 - pending : pending;
        std::vector<BfrFace> &batch = batches[making];
        spia_result handed = SPIA_OK;
        parallel_for(threads, count, kPieceFaces, [&](int64_t i0, int64_t i1, int thread) {
            try {
                if (thread == 0 && pending_f0 >= 0) handed = hand_over();
                Worker &w = workers[(size_t)thread];
                if (!w.factory || w.faces >= kFactoryFaces) {
                    w.factory.reset(new Bfr::RefinerSurfaceFactory<>(refiner, qopt));
                    w.faces = 0;
                }
                w.faces += i1 - i0;
                for (int64_t i = i0; i < i1; ++i) {
                    const int32_t f = f0 + (int32_t)i;
                    if (any_far && far_face[(size_t)f]) continue;
                    if (!bfr_face(*w.factory, f, p, sets, w.x, batch[(size_t)i]))
                        failed_face_of[(size_t)thread] = std::min(failed_face_of[(size_t)thread], f);
                }
            } catch (const std::bad_alloc &) {
                out_of_memory_of[(size_t)thread] = 1;
            } catch (...) {
                other_failure_of[(size_t)thread] = 1;
            }
        });
        if (pending_f0 >= 0) handed = hand_over();
        int32_t failed_face = INT32_MAX;
        for (int t = 0; t < threads; ++t) {
            if (out_of_memory_of[(size_t)t]) throw std::bad_alloc();
            if (other_failure_of[(size_t)t])
                return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing sample stencils");
            failed_face = std::min(failed_face, failed_face_of[(size_t)t]);
        }
        if (handed != SPIA_OK) return handed;
        if (failed_face != INT32_MAX)
            return spia__fail(status, SPIA_ERROR_INTERNAL, failed_face, "OpenSubdiv built no limit surface for face %d",
                              (int)failed_face);
        pending_f0 = f0, pending_count = count, pending = making;
    }
    if (pending_f0 >= 0 && (r = hand_over()) != SPIA_OK) return r;
    spia__ok(status);
    return SPIA_OK;
}

namespace {
// The blocks as a stencil table: rows in ptex order, exact zeros dropped,
// columns sorted.
struct RowsOut {
    std::vector<int64_t> offsets{0};
    std::vector<int32_t> indices;
    std::vector<double> weights;
    int32_t per = 0;
    static int add(void *user, int64_t, int32_t width, const int32_t *columns, const double *w) {
        RowsOut &o = *static_cast<RowsOut *>(user);
        try {
            for (int32_t j = 0; j < o.per; ++j) {
                for (int32_t i = 0; i < width; ++i)
                    if (w[(size_t)j * width + i] != 0.0) {
                        o.indices.push_back(columns[i]);
                        o.weights.push_back(w[(size_t)j * width + i]);
                    }
                o.offsets.push_back((int64_t)o.indices.size());
            }
        } catch (const std::bad_alloc &) {
            return SPIA_ERROR_OUT_OF_MEMORY;
        }
        return 0;
    }
};
}  // namespace

static spia_result surface(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, int32_t per_edge,
                           spia_stencils **out, spia_status *status) {
    const int64_t rows = spia_surface_sample_count(m, per_edge);
    if (rows > INT32_MAX / 64)
        return spia__fail(status, SPIA_ERROR_INVALID_ARGUMENT, -1,
                          "%lld samples are too many (at most %d): lower samples_per_edge", (long long)rows,
                          INT32_MAX / 64);
    RowsOut o;
    o.per = per_edge * per_edge;
    o.offsets.reserve((size_t)rows + 1);
    const std::vector<PointSet> sets{{SampleGrid(per_edge, false), RowsOut::add, &o}};
    spia_result r = surface_blocks(m, adj, opt, sets, status);
    if (r != SPIA_OK) return r;
    if ((int64_t)o.offsets.size() != rows + 1)
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "OpenSubdiv made %lld sample stencils for %lld samples",
                          (long long)o.offsets.size() - 1, (long long)rows);
    spia_stencils *s = spia__stencils_alloc((int32_t)rows, (int64_t)o.weights.size());
    if (!s) return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the sample stencils");
    std::copy(o.offsets.begin(), o.offsets.end(), s->offsets);
    std::copy(o.indices.begin(), o.indices.end(), s->indices);
    std::copy(o.weights.begin(), o.weights.end(), s->weights);
    s->nnz = (int64_t)o.weights.size();
    spia__stencils_canonicalize(s);
    *out = s;
    spia__ok(status);
    return SPIA_OK;
}

}  // namespace spia_osd

extern "C" spia_result spia__osd_surface_stencils(const spia_mesh *mesh, const spia_adjacency *adj,
                                                  const spia_options *options, int32_t samples_per_edge,
                                                  spia_stencils **out, spia_status *status) {
    *out = nullptr;
    try {
        return spia_osd::surface(mesh, adj, options, samples_per_edge, out, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing sample stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing sample stencils");
    }
}

extern "C" spia_result spia__osd_surface_blocks(const spia_mesh *mesh, const spia_adjacency *adj,
                                                const spia_options *options, const spia__block_points *sets,
                                                int32_t set_count, spia_status *status) {
    for (int32_t i = 0; i < set_count; ++i)
        if (sets[i].corners && sets[i].per_edge < 2)
            return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "a grid with corners needs two points an edge");
    try {
        std::vector<spia_osd::PointSet> points;
        for (int32_t i = 0; i < set_count; ++i)
            points.push_back({spia_osd::SampleGrid(sets[i].per_edge, sets[i].corners != 0), sets[i].emit, sets[i].user});
        return spia_osd::surface_blocks(mesh, adj, options, points, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing sample stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing sample stencils");
    }
}
