// SPDX-License-Identifier: GPL-3.0-or-later
// The limit stencil table through OpenSubdiv (spia__osd_limit_stencils):
// the closed-form rows (catmark_closed.c) and the semi-sharp fans' rows
// (6a) written in place, the other vertices through the steps of osd.h,
// Bfr at the corners step 5 chose (10), and the rows moved together (11).

#include "osd.h"

namespace spia_osd {

// Faces per Bfr factory (step 10): its cache of irregular patches lives that long.
const int32_t kFaceBlock = 131072;

// The table under construction, written in place: each row gets room for a
// bound on its length, is filled, sorted, merged and stripped of zeros
// there, and the rows are then moved together (finish).  A row longer than
// its bound (not expected) is kept aside and the arrays are rebuilt to fit.

namespace {
struct TableWriter {
    spia_stencils *s = nullptr;
    std::vector<int32_t> length;  // per row: its bound, then its length once written
    std::vector<std::pair<int32_t, std::vector<Entry>>> spilled;

    // Row v from entries in caller numbering (any order, repeats allowed):
    // stable sort by column, repeats added up in order, zeros dropped.
    void write(int32_t v, std::vector<Entry> &row, std::vector<std::pair<int32_t, std::vector<Entry>>> &spill) {
        for (size_t i = 1; i < row.size(); ++i) {
            Entry e = row[i];
            size_t j = i;
            while (j > 0 && row[j - 1].first > e.first) {
                row[j] = row[j - 1];
                --j;
            }
            row[j] = e;
        }
        size_t out = 0;
        for (size_t i = 0; i < row.size();) {
            const int32_t k = row[i].first;
            double w = 0.0;
            while (i < row.size() && row[i].first == k) w += row[i++].second;
            if (w != 0.0) row[out++] = Entry(k, w);
        }
        row.resize(out);
        length[(size_t)v] = (int32_t)out;
        if ((int64_t)out > s->offsets[v + 1] - s->offsets[v]) {
            spill.emplace_back(v, row);
            return;
        }
        for (size_t i = 0; i < out; ++i) {
            s->indices[s->offsets[v] + (int64_t)i] = row[i].first;
            s->weights[s->offsets[v] + (int64_t)i] = row[i].second;
        }
    }

    // 11. Rows moved together (or, if some were spilled, copied into arrays
    //     that fit them all).  Returns the finished table, or nullptr when
    //     out of memory (s is then still owned by the caller).
    spia_stencils *finish(int32_t n) {
        if (spilled.empty()) {
            int64_t pos = 0;
            for (int32_t v = 0; v < n; ++v) {
                const int64_t start = s->offsets[v];
                s->offsets[v] = pos;
                if (start != pos) {
                    memmove(s->indices + pos, s->indices + start, sizeof(int32_t) * (size_t)length[v]);
                    memmove(s->weights + pos, s->weights + start, sizeof(double) * (size_t)length[v]);
                }
                pos += length[v];
            }
            s->offsets[n] = pos;
            s->nnz = pos;
            spia__stencils_shrink(s);
            return s;
        }
        std::sort(spilled.begin(), spilled.end(),
                  [](const std::pair<int32_t, std::vector<Entry>> &a, const std::pair<int32_t, std::vector<Entry>> &b) {
                      return a.first < b.first;
                  });
        int64_t total = 0;
        for (int32_t v = 0; v < n; ++v) total += length[v];
        spia_stencils *t = spia__stencils_alloc(n, total);
        if (!t) return nullptr;
        size_t next = 0;
        int64_t pos = 0;
        for (int32_t v = 0; v < n; ++v) {
            t->offsets[v] = pos;
            if (next < spilled.size() && spilled[next].first == v) {
                for (const Entry &e : spilled[next].second) {
                    t->indices[pos] = e.first;
                    t->weights[pos++] = e.second;
                }
                ++next;
            } else {
                memcpy(t->indices + pos, s->indices + s->offsets[v], sizeof(int32_t) * (size_t)length[v]);
                memcpy(t->weights + pos, s->weights + s->offsets[v], sizeof(double) * (size_t)length[v]);
                pos += length[v];
            }
        }
        t->offsets[n] = pos;
        t->nnz = pos;
        spia_stencils_free(s);
        s = t;
        return t;
    }
};
}  // namespace

// 10. Bfr at the corners chosen in step 5: at its default options, unless
//     the face also gives a vertex at the isolation level: then the face's
//     one surface at that level serves both (closed-form vertices come out
//     the same from Blender's patches at any level).  Faces are shared out
//     among threads; each row comes from one face, so the table is the same
//     whatever the number of threads.  Faces go in blocks of kFaceBlock,
//     each with factories of its own and so its own cache of irregular
//     patches (keyed by topology): a cache shared between threads measured
//     no faster with two threads than with one, its lock taken for every
//     face, and one cache per thread for the whole mesh grew to 1.6 kB a
//     vertex on the creased 1M-vertex sphere (0.85 kB per block, for about
//     the same time).
static spia_result bfr_rows(const spia_mesh *m, const int64_t *corner_start, const spia_options *opt, const Prepared &p,
                            const Part &part, const Evaluation &ev, TableWriter &table, spia_status *status) {
    Bfr::SurfaceFactory::Options qopt;
    qopt.SetApproxLevelSharp(opt->quality).SetApproxLevelSmooth(opt->quality);
    const Far::TopologyRefiner &refiner = *part.refiner;
    const int32_t face_count = refiner.GetLevel(0).GetNumFaces();
    const int threads = opt->threads > 0 ? opt->threads : 1;
    std::vector<int32_t> failed_face_of((size_t)threads, INT32_MAX);  // per thread, the first face Bfr failed on
    std::vector<unsigned char> out_of_memory_of((size_t)threads, 0), other_failure_of((size_t)threads, 0);
    std::vector<std::vector<std::pair<int32_t, std::vector<Entry>>>> spill_of((size_t)threads);
    const int32_t blocks = (face_count + kFaceBlock - 1) / kFaceBlock;
    parallel_for(threads, blocks, 1, [&](int64_t fb0, int64_t fb1, int thread) {
        try {
            Bfr::Surface<double> srf;
            std::vector<Far::Index> cv;
            std::vector<double> w;
            std::vector<Entry> row;
            for (int32_t fb = (int32_t)fb0; fb < (int32_t)fb1; ++fb) {
                Bfr::RefinerSurfaceFactory<> factory(refiner, Bfr::SurfaceFactory::Options()),
                    qfactory(refiner, qopt);
                const int32_t i_end = (int32_t)std::min<int64_t>(face_count, (int64_t)(fb + 1) * kFaceBlock);
                for (int32_t i = fb * kFaceBlock; i < i_end; ++i) {
                    const int32_t f = part.mesh_face(i);
                    bool initialized = false;
                    const bool q = !ev.level_face.empty() && ev.level_face[f];
                    for (int64_t c = corner_start[f]; c < corner_start[f + 1]; ++c) {
                        const int32_t o = p.osd_of[m->face_vertices[c]];
                        if (ev.bfr_corner[o] != c) continue;
                        if (!initialized) {
                            if (!(q ? qfactory.InitVertexSurface(i, &srf) : factory.InitVertexSurface(i, &srf)) ||
                                !srf.IsValid()) {
                                failed_face_of[(size_t)thread] = std::min(failed_face_of[(size_t)thread], f);
                                break;
                            }
                            initialized = true;
                            cv.resize((size_t)srf.GetNumControlPoints());
                            w.resize(cv.size());
                            srf.GetControlPointIndices(cv.data());
                        }
                        double uv[2];
                        srf.GetParameterization().GetVertexCoord((int)(c - corner_start[f]), uv);
                        srf.EvaluateStencil(uv, w.data());
                        row.clear();
                        for (size_t k = 0; k < cv.size(); ++k)
                            if (w[k] != 0.0) row.emplace_back(p.vertex_of[part.osd(cv[k])], w[k]);
                        table.write(m->face_vertices[c], row, spill_of[(size_t)thread]);
                    }
                }
            }
        } catch (const std::bad_alloc &) {
            out_of_memory_of[(size_t)thread] = 1;
        } catch (...) {
            other_failure_of[(size_t)thread] = 1;
        }
    });
    int32_t failed_face = INT32_MAX;
    bool out_of_memory = false, other_failure = false;
    for (int t = 0; t < threads; ++t) {
        failed_face = std::min(failed_face, failed_face_of[(size_t)t]);
        out_of_memory = out_of_memory || out_of_memory_of[(size_t)t];
        other_failure = other_failure || other_failure_of[(size_t)t];
    }
    if (out_of_memory) throw std::bad_alloc();
    if (other_failure) return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing limit stencils");
    if (failed_face != INT32_MAX)
        return spia__fail(status, SPIA_ERROR_INTERNAL, failed_face, "OpenSubdiv built no limit surface for face %d",
                          (int)failed_face);
    for (auto &part_spill : spill_of)
        for (auto &r : part_spill) table.spilled.push_back(std::move(r));
    return SPIA_OK;
}

// The sharpness of p as catmark_closed.c reads it.
static spia_catmark_sharpness sharpness_view(const Prepared &p, const spia_options *opt) {
    spia_catmark_sharpness sh;
    sh.vertex = p.vertex_sharpness.data();
    sh.crease_first = p.crease_first.empty() ? nullptr : p.crease_first.data();
    sh.crease_other = p.crease_other.empty() ? nullptr : p.crease_other.data();
    sh.crease_sharpness = p.crease_sharpness.empty() ? nullptr : p.crease_sharpness.data();
    sh.preserve_corners = opt->boundary_smooth == SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS;
    return sh;
}

// 6a on the threads, each row written into the table; the vertices it
// takes no longer need OpenSubdiv.
static void fan_ring_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, const Prepared &p,
                          TableWriter &table, const unsigned char *on_boundary) {
    const int threads = opt->threads > 0 ? opt->threads : 1;
    const spia_catmark_sharpness sh = sharpness_view(p, opt);
    std::vector<std::vector<std::pair<int32_t, std::vector<Entry>>>> spill_of((size_t)threads);
    std::atomic<bool> out_of_memory(false);
    parallel_for(threads, m->vertex_count, 4096, [&](int64_t v0, int64_t v1, int thread) {
        try {
            Ring ring;
            RingScratch scratch;
            std::vector<int32_t> next, prev;
            std::vector<Entry> row;
            for (int32_t v = (int32_t)v0; v < (int32_t)v1; ++v) {
                if (table.length[(size_t)v] >= 0 || on_boundary[v] > 1) continue;
                const int levels = fan_ring(m, adj, p, sh, opt, v, on_boundary[v] == 1, next, prev, ring);
                if (levels == 0 || !ring_row(m, adj, ring, p.vertex_sharpness[(size_t)v], levels, p.sdc, scratch, row))
                    continue;
                table.write(v, row, spill_of[(size_t)thread]);
            }
        } catch (const std::bad_alloc &) {
            out_of_memory = true;
        }
    });
    if (out_of_memory) throw std::bad_alloc();
    for (auto &part_spill : spill_of)
        for (auto &r : part_spill) table.spilled.push_back(std::move(r));
}

// The closed-form rows (catmark_closed.c), on the threads, written into
// the table; the vertices they do not cover (no closed form) get length -1.
static void closed_rows(const spia_mesh *m, const spia_adjacency *adj, const spia_options *opt, const Prepared &p,
                        TableWriter &table, unsigned char *on_boundary) {
    const spia_catmark_sharpness sh = sharpness_view(p, opt);
    const int threads = opt->threads > 0 ? opt->threads : 1;
    std::atomic<bool> out_of_memory(false);
    spia_stencils *s = table.s;
    parallel_for(threads, m->vertex_count, 4096, [&](int64_t v0, int64_t v1, int) {
        spia_row_scratch scratch;
        memset(&scratch, 0, sizeof scratch);
        scratch.build = 1;
        for (int32_t v = (int32_t)v0; v < (int32_t)v1 && !out_of_memory; ++v) {
            if (p.osd_of[v] < 0) continue;
            const int32_t len = spia__catmark_closed_row(m, adj, &sh, v, &scratch);
            if (scratch.on_boundary >= 0) on_boundary[v] = (unsigned char)scratch.on_boundary;
            if (len == SPIA__ROW_OUT_OF_MEMORY) {
                out_of_memory = true;
            } else if (len < 0 || len > s->offsets[v + 1] - s->offsets[v]) {
                table.length[(size_t)v] = -1;  // (a closed row is never longer than its room)
            } else {
                for (int32_t k = 0; k < len; ++k) {
                    s->indices[s->offsets[v] + k] = scratch.entries[k].column;
                    s->weights[s->offsets[v] + k] = scratch.entries[k].weight;
                }
                table.length[(size_t)v] = len;
            }
        }
        spia__row_scratch_free(&scratch);
    });
    if (out_of_memory) throw std::bad_alloc();
}

// 9. Each row's room.  For Loop, where every row comes from OpenSubdiv, the
//    distinct vertices of the vertex's faces, on which its limit point
//    alone depends.  For Catmull-Clark, where most rows have a closed form,
//    that row's length for a smooth interior vertex, 1 + sum (|f| - 2)
//    (and at least 3, a crease's): the table is made before it is known
//    which vertices need OpenSubdiv, and a row from it that does not fit
//    is kept aside (TableWriter).  Vertices no face uses: 1, or 3 where
//    two loose edges smooth them.
static std::vector<int32_t> row_room(const spia_mesh *m, const spia_adjacency *adj, const Prepared &p,
                                     const std::vector<int32_t> &loose_degree) {
    const int32_t n = m->vertex_count;
    std::vector<int32_t> room((size_t)n, 0);
    std::vector<int32_t> stamp;
    if (!p.blender) stamp.assign((size_t)p.osd_n, -1);
    for (int32_t v = 0; v < n; ++v) {
        const int32_t o = p.osd_of[v];
        int32_t count = 0;
        if (o < 0) {
            count = !loose_degree.empty() && loose_degree[v] == 2 ? 3 : 1;
        } else if (p.blender) {
            int64_t sum = 1;
            for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
                const int32_t f = adj->face_of_corner[adj->corner_of[i]];
                sum += adj->corner_start[f + 1] - adj->corner_start[f] - 2;
            }
            count = (int32_t)std::min<int64_t>(std::max<int64_t>(sum, 3), INT32_MAX);
        } else {
            for (int64_t i = adj->first[v]; i < adj->first[v + 1]; ++i) {
                const int32_t f = adj->face_of_corner[adj->corner_of[i]];
                for (int64_t c = adj->corner_start[f]; c < adj->corner_start[f + 1]; ++c) {
                    const int32_t u = p.osd_of[m->face_vertices[c]];
                    if (stamp[u] != o) {
                        stamp[u] = o;
                        ++count;
                    }
                }
            }
        }
        room[(size_t)v] = count;
    }
    return room;
}

// 8. Each vertex no face uses, its number of loose edges (up to two
//    counted) and their other ends (Catmull-Clark only; empty otherwise).
static void loose_edges(const spia_mesh *m, const Prepared &p, std::vector<int32_t> &loose_degree,
                        std::vector<int32_t> &loose_ends) {
    const int32_t n = m->vertex_count;
    if (p.blender && p.osd_n < n && m->edge_count > 0) {
        loose_degree.assign((size_t)n, 0);
        loose_ends.assign(2 * (size_t)n, -1);
        for (int32_t e = 0; e < m->edge_count; ++e)
            for (int k = 0; k < 2; ++k) {
                int32_t v = m->edges[2 * (int64_t)e + k], w = m->edges[2 * (int64_t)e + 1 - k];
                if (p.osd_of[v] >= 0) continue;
                if (loose_degree[v] < 2) loose_ends[2 * (size_t)v + loose_degree[v]] = w;
                ++loose_degree[v];
            }
    }
}

// The rows of the vertices no face uses (8), and the held rows (6c, 7),
// written into the table; the held rows' memory is given back.
static void write_loose_and_held(const spia_mesh *m, const Prepared &p, const std::vector<int32_t> &loose_degree,
                                 const std::vector<int32_t> &loose_ends, HeldRows &held, TableWriter &table) {
    std::vector<Entry> row;
    for (int32_t v = 0; v < m->vertex_count; ++v) {
        const int32_t o = p.osd_of[v];
        row.clear();
        if (o < 0) {
            const bool smoothed = !loose_degree.empty() && loose_degree[v] == 2;
            row.emplace_back(v, smoothed ? 4.0 / 6.0 : 1.0);
            if (smoothed)
                for (int k = 0; k < 2; ++k) row.emplace_back(loose_ends[2 * (size_t)v + k], 1.0 / 6.0);
        } else if (!held.start.empty() && held.start[o] >= 0) {
            for (int32_t k = 0; k < held.size[o]; ++k)
                row.emplace_back(held.indices[held.start[o] + k], held.weights[held.start[o] + k]);
        } else {
            continue;
        }
        table.write(v, row, table.spilled);
    }
    std::vector<int32_t>().swap(held.indices);
    std::vector<double>().swap(held.weights);
}

static spia_result build(const spia_mesh *m, spia_adjacency *adj_lists, const spia_options *opt,
                         unsigned char *on_boundary, spia_stencils **out, spia_status *status) {
    const spia_adjacency *adj = adj_lists;
    Prepared p;
    spia_result r = prepare_sharpness(m, adj, opt, p);
    if (r != SPIA_OK) return r;
    const int32_t n = m->vertex_count;

    // 8. Vertices no face uses keep their position, except that Blender
    //    smooths a vertex with exactly two (loose) edges along them:
    //    (prev + 4 V + next) / 6.
    std::vector<int32_t> loose_degree, loose_ends;
    loose_edges(m, p, loose_degree, loose_ends);

    // 9. The table, with room for each row.
    TableWriter table;
    table.length = row_room(m, adj, p, loose_degree);
    int64_t capacity = 0;
    for (int32_t v = 0; v < n; ++v) capacity += table.length[(size_t)v];
    table.s = spia__stencils_alloc(n, capacity);
    if (!table.s)
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for %lld stencil weights",
                          (long long)capacity);
    std::unique_ptr<spia_stencils, void (*)(spia_stencils *)> owner(table.s, spia_stencils_free);
    for (int32_t v = 0; v < n; ++v) table.s->offsets[v + 1] = table.s->offsets[v] + table.length[(size_t)v];

    // The closed-form rows (Catmull-Clark) and the semi-sharp vertices of
    // one fan from their ring in the mesh (6a), and the vertices left for
    // OpenSubdiv (all, for Loop).
    if (p.blender) {
        closed_rows(m, adj, opt, p, table, on_boundary);
        fan_ring_rows(m, adj, opt, p, table, on_boundary);
    }
    std::vector<int32_t> wanted;
    for (int32_t o = 0; o < p.osd_n; ++o)
        if (!p.blender || table.length[(size_t)p.vertex_of[o]] < 0) wanted.push_back(o);

    // OpenSubdiv's refiner on the faces within two rings of those vertices
    // (the whole mesh when that is all of it), in a spatial order where the
    // mesh's scatters them (part_face_order); the adaptive rows (step 7).
    Part part;
    Evaluation ev;
    HeldRows held;
    if (!wanted.empty()) {
        std::vector<char> in_part = two_ring_faces(m, adj, p, wanted);
        if (std::find(in_part.begin(), in_part.end(), 0) == in_part.end()) in_part.clear();
        r = make_part(m, adj, opt, p, in_part, true, p.blender ? on_boundary : nullptr, part, status);
        if (r != SPIA_OK) return r;
        choose_evaluation(m, adj, opt, p, part, wanted, ev);
        r = adaptive_rows(m, adj, opt, p, ev, held, status);
        if (r != SPIA_OK) return r;
        r = ring_rows(opt, p, part, ev, held, status);
        if (r != SPIA_OK) return r;
    }
    // Vertices no face uses, and the adaptive rows.
    write_loose_and_held(m, p, loose_degree, loose_ends, held, table);
    // The boundary vertices the closed rows did not learn, then (only
    // corner_start is needed from here on) the vertex lists make room.
    if (spia__boundary_vertices_unknown(m, adj, on_boundary, opt->threads > 0 ? opt->threads : 1) != SPIA_OK)
        throw std::bad_alloc();
    spia__adjacency_release_vertex_lists(adj_lists);
    adj = nullptr;
    if (part.refiner) {
        r = bfr_rows(m, adj_lists->corner_start, opt, p, part, ev, table, status);
        if (r != SPIA_OK) return r;
    }
    owner.release();
    spia_stencils *done = table.finish(n);
    if (!done) {
        spia_stencils_free(table.s);
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory for the stencil table");
    }
    *out = done;
    spia__ok(status);
    return SPIA_OK;
}

}  // namespace spia_osd

extern "C" spia_result spia__osd_limit_stencils(const spia_mesh *mesh, spia_adjacency *adj,
                                                    const spia_options *options, unsigned char *on_boundary,
                                                    spia_stencils **out, spia_status *status) {
    *out = nullptr;
    try {
        return spia_osd::build(mesh, adj, options, on_boundary, out, status);
    } catch (const std::bad_alloc &) {
        return spia__fail(status, SPIA_ERROR_OUT_OF_MEMORY, -1, "out of memory computing limit stencils");
    } catch (...) {
        return spia__fail(status, SPIA_ERROR_INTERNAL, -1, "unexpected failure computing limit stencils");
    }
}
