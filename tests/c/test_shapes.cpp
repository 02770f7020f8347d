// SPDX-License-Identifier: GPL-3.0-or-later
// One of OpenSubdiv's regression shapes (regression/shapes/NAME.h in its
// source package, read at test time: no shape data is compiled in) through
// the library, in every configuration that applies to it:
//   catmark_*  Catmull-Clark, and Doo-Sabin where the library takes the mesh;
//   loop_*     Loop with both boundary rules, and Catmull-Clark (Blender's
//              modifier takes triangles);
// each with both boundary_smooth values, qualities 1, 3 and 6, creases on
// and off.  Each configuration builds the limit stencils and solves for the
// cage through the shape's own positions: a call fails only as a refusal
// with a message (never SPIA_ERROR_INTERNAL, never SPIA_ERROR_DIVERGED), a
// solved cage's limit points are within the tolerance, a stagnated one is
// within 1e-5 on the reachable vertices and a least-squares solution.  The
// Catmull-Clark stencils are checked against OpenSubdiv's own
// LimitStencilTableFactory on a full adaptive refinement set up as Blender
// does (reference.h).
//
// Shapes out of scope (bilinear_*, holes, Chaikin creases, hierarchical
// edits, OpenSubdiv's smooth-triangle rule) are not registered as tests
// (tests/c/CMakeLists.txt picks them out by the same rules); named here,
// they fail.
//
//   test_shapes PATH/TO/SHAPE.h... [--full] [--sanitized]
// Each shape named in turn (ctest gives each its own process; under Wine,
// where starting a process costs seconds, one process takes them all).
// --full: the factory's tables at every quality on vertices of valence
// over 100 too (a minute a table); --sanitized: the sanitizer build's
// subset (Loop's smooth rule at quality 3 only).
#include "reference.h"

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>
#include <tuple>

namespace {

// A tag line, "t name nints/nfloats/nstrings ints... floats... strings...",
// parsed as OpenSubdiv's Shape::tag::parseTag does.
struct Tag {
    std::string name;
    std::vector<int> ints;
    std::vector<float> floats;
    std::vector<std::string> strings;
};

struct Shape {
    std::vector<float> verts;  // x y z per vertex
    std::vector<int> sizes, fv;
    std::vector<Tag> tags;
};

// The text of the header's string: every literal after the '=' of
// "static const std::string NAME =" up to the ';', escapes resolved.
bool shape_text(const std::string &file, std::string &out) {
    size_t at = file.find("std::string");
    if (at == std::string::npos) return false;
    at = file.find('=', at);
    if (at == std::string::npos) return false;
    for (size_t i = at + 1; i < file.size(); ++i) {
        const char c = file[i];
        if (c == ';') return !out.empty();
        if (c == '/' && i + 1 < file.size() && file[i + 1] == '/') {
            while (i < file.size() && file[i] != '\n') ++i;
            continue;
        }
        if (c != '"') continue;
        for (++i; i < file.size() && file[i] != '"'; ++i) {
            if (file[i] != '\\') {
                out += file[i];
                continue;
            }
            if (++i >= file.size()) return false;
            switch (file[i]) {
            case 'n': out += '\n'; break;
            case 't': out += '\t'; break;
            case 'r': out += '\r'; break;
            default: out += file[i]; break;  // \" \\ \'
            }
        }
    }
    return false;
}

bool parse_tag(const char *line, Tag &t) {
    const char *cp = line + 2;
    char name[64];
    while (*cp == ' ') cp++;
    if (sscanf(cp, "%63s", name) != 1) return false;
    while (*cp && *cp != ' ') cp++;
    int ni = 0, nf = 0, ns = 0;
    while (*cp == ' ') cp++;
    if (sscanf(cp, "%d/%d/%d", &ni, &nf, &ns) != 3) return false;
    while (*cp && *cp != ' ') cp++;
    t.name = name;
    for (int i = 0; i < ni; ++i) {
        int v;
        while (*cp == ' ') cp++;
        if (sscanf(cp, "%d", &v) != 1) return false;
        t.ints.push_back(v);
        while (*cp && *cp != ' ') cp++;
    }
    for (int i = 0; i < nf; ++i) {
        float v;
        while (*cp == ' ') cp++;
        if (sscanf(cp, "%f", &v) != 1) return false;
        t.floats.push_back(v);
        while (*cp && *cp != ' ') cp++;
    }
    for (int i = 0; i < ns; ++i) {
        char v[512];
        while (*cp == ' ') cp++;
        if (sscanf(cp, "%511s", v) != 1) return false;
        t.strings.push_back(v);
        while (*cp && *cp != ' ') cp++;
    }
    return true;
}

// OpenSubdiv's Shape::parseObj, for positions, faces and tags.
void parse_obj(const std::string &text, Shape &s) {
    std::istringstream in(text);
    std::string l;
    while (std::getline(in, l)) {
        const char *line = l.c_str();
        if (line[0] == 'v' && line[1] == ' ') {
            float x, y, z;
            if (sscanf(line, "v %f %f %f", &x, &y, &z) == 3) s.verts.insert(s.verts.end(), {x, y, z});
        } else if (line[0] == 'f' && line[1] == ' ') {
            const char *cp = line + 2;
            while (*cp == ' ') cp++;
            int vi, ti, ni, n = 0;
            while (sscanf(cp, "%d/%d/%d", &vi, &ti, &ni) > 0) {
                ++n;
                s.fv.push_back(vi - 1);
                while (*cp && *cp != ' ') cp++;
                while (*cp == ' ') cp++;
            }
            s.sizes.push_back(n);
        } else if (line[0] == 't' && line[1] == ' ') {
            Tag t;
            if (parse_tag(line, t)) s.tags.push_back(t);
        }
    }
}

// Why the shape is out of scope, or "".
std::string out_of_scope(const std::string &name, const Shape &s) {
    if (name.rfind("bilinear_", 0) == 0) return "bilinear scheme";
    if (name.rfind("catmark_", 0) != 0 && name.rfind("loop_", 0) != 0) return "unknown scheme prefix";
    for (const Tag &t : s.tags) {
        if (t.name == "hole") return "holes";
        if (t.name == "creasemethod" && !t.strings.empty() && t.strings[0] == "chaikin") return "Chaikin creases";
        if (t.name == "vertexedit" || t.name == "edgeedit" || t.name == "faceedit") return "hierarchical edits";
        if (t.name == "smoothtriangles" && !t.strings.empty() && t.strings[0] == "smooth")
            return "the smooth-triangle rule";
    }
    return "";
}

// Blender's crease c for OpenSubdiv's sharpness s: 10 c^2 = s.
float crease_of(float s) { return (float)std::sqrt(std::min((double)s, 10.0) / 10.0); }

// The shape as a tmesh with its crease and corner tags as Blender creases,
// each edge and vertex once, its last tag winning as in OpenSubdiv's
// far_utils.h (sharpness floatargs[j] for the j-th int when there are
// several floats, else floatargs[0]; below 0 taken as 0).  False, with a
// message, where OpenSubdiv would refuse the tags.
bool build_mesh(const Shape &s, tmesh &m, std::string &error) {
    memset(&m, 0, sizeof m);
    const int nv = (int)s.verts.size() / 3;
    for (int v = 0; v < nv; ++v) tmesh_vertex(&m, s.verts[3 * v], s.verts[3 * v + 1], s.verts[3 * v + 2]);
    size_t c = 0;
    std::set<std::pair<int, int>> face_edges;
    for (int n : s.sizes) {
        tmesh_face(&m, n, &s.fv[c]);
        for (int k = 0; k < n; ++k) {
            const int a = s.fv[c + k], b = s.fv[c + (k + 1) % n];
            face_edges.insert(std::make_pair(std::min(a, b), std::max(a, b)));
        }
        c += (size_t)n;
    }
    std::map<std::pair<int, int>, float> edge_sharpness;
    std::map<int, float> vertex_sharpness;
    for (const Tag &t : s.tags) {
        if (t.name != "crease" && t.name != "corner") continue;
        const int nfloat = (int)t.floats.size();
        auto sharpness = [&](int j, float &out) {
            const int at = nfloat > 1 ? j : 0;
            if (at >= nfloat) return false;
            out = std::max(0.0f, t.floats[(size_t)at]);
            return true;
        };
        if (t.name == "crease") {
            for (int j = 0; j < (int)t.ints.size() - 1; j += 2) {
                const auto e = std::make_pair(std::min(t.ints[j], t.ints[j + 1]), std::max(t.ints[j], t.ints[j + 1]));
                float sh;
                if (!face_edges.count(e) || !sharpness(j, sh)) {
                    error = "crease tag on edge (" + std::to_string(t.ints[j]) + "," + std::to_string(t.ints[j + 1]) +
                            ") that no face has, or without its sharpness";
                    return false;
                }
                edge_sharpness[e] = sh;
            }
        } else {
            for (int j = 0; j < (int)t.ints.size(); ++j) {
                float sh;
                if (t.ints[j] < 0 || t.ints[j] >= nv || !sharpness(j, sh)) {
                    error = "corner tag on vertex " + std::to_string(t.ints[j]) + " out of range or without sharpness";
                    return false;
                }
                vertex_sharpness[t.ints[j]] = sh;
            }
        }
    }
    for (const auto &kv : edge_sharpness)
        if (kv.second > 0.0f) tmesh_edge(&m, kv.first.first, kv.first.second, crease_of(kv.second));
    for (const auto &kv : vertex_sharpness)
        if (kv.second > 0.0f) tmesh_vertex_crease(&m, kv.first, crease_of(kv.second));
    return true;
}

// The factory's rows, by (quality, preserve corners, creases that matter).
std::map<std::tuple<int, bool, bool>, Rows> reference_cache;
// The factory takes about a minute a table on a vertex of valence 360 at
// quality 3 or more (the library a few milliseconds): such shapes are
// compared at quality 1 only, unless --full.
int max_reference_quality = 10, max_valence = 0;
// The most faces the uniform Loop reference refines to (fewer under the
// sanitizers).
int64_t loop_reference_faces = 1 << 21;
// Its rows by (preserve corners, creases), for the shape at hand (Loop's
// limit does not depend on the quality).
std::map<std::pair<bool, bool>, Rows> loop_reference_cache;

struct Stats {
    int configs = 0, ok = 0, refused = 0, stagnated = 0, max_iterations = 0;
    double worst_reference = 0.0, worst_lsq = 0.0;
};

const char *scheme_name(spia_scheme s, spia_boundary_rule r) {
    switch (s) {
    case SPIA_SCHEME_CATMULL_CLARK: return "catmark";
    case SPIA_SCHEME_LOOP: return r == SPIA_BOUNDARY_RULE_HOPPE ? "loop-hoppe" : "loop-smooth";
    case SPIA_SCHEME_DOO_SABIN: return "doo-sabin";
    }
    return "?";
}

// Applies CSR rows (or Rows) to positions, 3 doubles per point.
std::vector<double> apply_rows(const Rows &rows, const std::vector<double> &x) {
    std::vector<double> out(rows.size() * 3, 0.0);
    for (size_t i = 0; i < rows.size(); ++i)
        for (const auto &kv : rows[i])
            for (int d = 0; d < 3; ++d) out[3 * i + d] += kv.second * x[3 * (size_t)kv.first + d];
    return out;
}

double distance(const double *a, const double *b) {
    return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

void run(const std::string &shape, const tmesh &m, spia_scheme scheme, spia_boundary_rule rule, bool preserve,
         int quality, bool creases, Stats &stats) {
    const double tolerance = 1e-6;
    const int32_t n = m.nv;
    spia_mesh mesh = tmesh_view(&m);
    spia_options o = spia_options_default();
    o.scheme = scheme;
    o.boundary_rule = rule;
    o.boundary_smooth = preserve ? SPIA_BOUNDARY_SMOOTH_PRESERVE_CORNERS : SPIA_BOUNDARY_SMOOTH_ALL;
    o.quality = quality;
    o.ignore_creases = creases ? 0 : 1;
    char where[200];
    snprintf(where, sizeof where, "%s %s %s q%d %s", shape.c_str(), scheme_name(scheme, rule),
             preserve ? "corners" : "all", quality, creases ? "creases" : "no-creases");
    ++stats.configs;

    std::vector<double> P((size_t)n * 3);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < P.size(); ++i) {
        P[i] = m.pos[i];
        lo[i % 3] = std::min(lo[i % 3], P[i]);
        hi[i % 3] = std::max(hi[i % 3], P[i]);
    }
    const double diagonal = std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                                      (hi[2] - lo[2]) * (hi[2] - lo[2]));

    typedef std::chrono::steady_clock Clock;
    auto since = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
    Clock::time_point t0 = Clock::now();
    double t_stencils = 0.0, t_reference = 0.0, t_solve = 0.0;
    spia_stencils *s = nullptr;
    spia_status st;
    memset(&st, 0, sizeof st);
    spia_result r = spia_limit_stencils_create(&mesh, &o, &s, &st);
    t_stencils = since(t0);
    CHECK(r != SPIA_ERROR_INTERNAL, "%s: stencils: internal error: %s", where, st.message);
    if (r != SPIA_OK) {
        CHECK(r < 0 && st.code == r && st.message[0] != '\0', "%s: stencils: %s without a message", where,
              spia_result_name(r));
        CHECK(s == nullptr, "%s: a refusal left a table", where);
        ++stats.refused;
        printf("%-60s %-28s unreachable -  worst -         (stencils: %s)\n", where, spia_result_name(r), st.message);
        return;
    }
    CHECK(spia_stencils_row_count(s) == n, "%s: %d rows for %d vertices", where, (int)spia_stencils_row_count(s), (int)n);
    std::vector<int64_t> off((size_t)n + 1);
    std::vector<int32_t> idx((size_t)spia_stencils_weight_count(s));
    std::vector<double> w(idx.size());
    CHECK(spia_stencils_copy_csr(s, off.data(), idx.data(), w.data()) == SPIA_OK, "%s: copy_csr", where);

    // Catmull-Clark: the rows against OpenSubdiv's factory, applied to the
    // shape's positions (and weight by weight, for the record).
    char reference[96] = "";
    if (scheme == SPIA_SCHEME_CATMULL_CLARK && quality > max_reference_quality) {
        snprintf(reference, sizeof reference, "  osd skipped (valence %d)", max_valence);
    } else if (scheme == SPIA_SCHEME_CATMULL_CLARK) {
        t0 = Clock::now();
        // (the same table whenever the creases make no difference)
        const bool any_creases = m.ne > 0 || m.vertex_creases;
        const std::tuple<int, bool, bool> key(quality, preserve, creases && any_creases);
        auto cached = reference_cache.find(key);
        if (cached == reference_cache.end())
            cached = reference_cache.emplace(key, reference_rows(m, quality, preserve, creases)).first;
        const Rows &ref = cached->second;
        t_reference = since(t0);
        Rows lib((size_t)n);
        for (int32_t i = 0; i < n; ++i)
            for (int64_t k = off[(size_t)i]; k < off[(size_t)i + 1]; ++k) lib[(size_t)i][idx[(size_t)k]] += w[(size_t)k];
        std::vector<double> a = apply_rows(ref, P), b = apply_rows(lib, P);
        double worst = 0.0, weight = 0.0;
        int at = -1;
        for (int32_t i = 0; i < n; ++i) {
            const double d = distance(&a[3 * (size_t)i], &b[3 * (size_t)i]) / diagonal;
            if (d > worst) worst = d, at = i;
            std::map<int, double> row = lib[(size_t)i];
            for (const auto &kv : ref[(size_t)i]) row[kv.first] -= kv.second;
            for (const auto &kv : row) weight = std::max(weight, std::fabs(kv.second));
        }
        CHECK(worst <= 1e-6, "%s: the library's limit points differ from OpenSubdiv's factory's by %g of the "
                             "diagonal at vertex %d (weights by up to %g)", where, worst, at, weight);
        stats.worst_reference = std::max(stats.worst_reference, worst);
        snprintf(reference, sizeof reference, "  osd %.1e (w %.1e)", worst, weight);
    } else if (scheme == SPIA_SCHEME_LOOP && rule == SPIA_BOUNDARY_RULE_SMOOTH) {
        // Loop: every weight against the whole mesh refined uniformly until
        // its semi-sharp creases have decayed (reference.h), where that fits.
        t0 = Clock::now();
        const std::pair<bool, bool> key(preserve, creases);
        auto cached = loop_reference_cache.find(key);
        if (cached == loop_reference_cache.end()) {
            Rows rows;
            if (!loop_uniform_rows(m, preserve, creases, loop_reference_faces, rows)) rows.clear();
            cached = loop_reference_cache.emplace(key, rows).first;
        }
        const Rows &ref = cached->second;
        if (!ref.empty()) {
            double weight = 0.0;
            int at = -1;
            for (int32_t i = 0; i < n; ++i) {
                std::map<int, double> row;
                for (int64_t k = off[(size_t)i]; k < off[(size_t)i + 1]; ++k) row[idx[(size_t)k]] += w[(size_t)k];
                for (const auto &kv : ref[(size_t)i]) row[kv.first] -= kv.second;
                for (const auto &kv : row)
                    if (std::fabs(kv.second) > weight) weight = std::fabs(kv.second), at = i;
            }
            CHECK(weight <= 1e-12, "%s: a Loop weight differs from the uniform refinement's by %g at vertex %d",
                  where, weight, at);
            snprintf(reference, sizeof reference, "  uniform w %.1e", weight);
        } else {
            snprintf(reference, sizeof reference, "  uniform too large");
        }
        t_reference = since(t0);
    }

    std::vector<float> cage((size_t)n * 3, 12345.0f);
    std::vector<uint8_t> flags((size_t)n, 0xAA);
    spia_report rep;
    memset(&rep, 0, sizeof rep);
    rep.unreachable = flags.data();
    memset(&st, 0, sizeof st);
    t0 = Clock::now();
    r = spia_solve(s, m.pos, &o, cage.data(), &rep, &st);
    t_solve = since(t0);
    CHECK(r != SPIA_ERROR_INTERNAL, "%s: solve: internal error: %s", where, st.message);
    CHECK(r != SPIA_ERROR_DIVERGED, "%s: solve diverged: %s", where, st.message);
    CHECK(rep.result == r, "%s: report says %s, call returned %s", where, spia_result_name(rep.result),
          spia_result_name(r));
    if (r < 0) {
        CHECK(st.code == r && st.message[0] != '\0', "%s: solve: %s without a message", where, spia_result_name(r));
        bool untouched = true;
        for (float x : cage) untouched = untouched && x == 12345.0f;
        CHECK(untouched, "%s: a failed solve wrote the cage", where);
        ++stats.refused;
        printf("%-60s %-28s unreachable -  worst -         (solve: %s)%s\n", where, spia_result_name(r), st.message,
               reference);
        spia_stencils_free(s);
        return;
    }
    CHECK(std::fabs(rep.diagonal - diagonal) <= 1e-12 * diagonal, "%s: diagonal %g, the test's %g", where,
          rep.diagonal, diagonal);
    std::vector<double> V(cage.begin(), cage.end()), LV((size_t)n * 3);
    CHECK(spia_stencils_apply(s, V.data(), LV.data()) == SPIA_OK, "%s: apply", where);
    int32_t set = 0;
    bool flags_valid = true;
    double worst = 0.0;  // over the reachable vertices, relative to the diagonal
    for (int32_t i = 0; i < n; ++i) {
        flags_valid = flags_valid && flags[(size_t)i] <= 1;
        set += flags[(size_t)i] == 1;
        if (flags[(size_t)i] != 1) worst = std::max(worst, distance(&LV[3 * (size_t)i], &P[3 * (size_t)i]) / diagonal);
    }
    CHECK(flags_valid, "%s: unreachable flags other than 0 and 1 (or not written)", where);
    CHECK(rep.unreachable_count == set, "%s: unreachable_count %d, %d flags set", where, (int)rep.unreachable_count,
          (int)set);
    char extra[96] = "";
    if (r == SPIA_OK) {
        ++stats.ok;
        CHECK(set == 0, "%s: SPIA_OK with %d unreachable vertices", where, (int)set);
        CHECK(worst <= tolerance * (1.0 + 1e-9), "%s: SPIA_OK but a limit point is off by %g of the diagonal", where,
              worst);
    } else {
        r == SPIA_STAGNATED ? ++stats.stagnated : ++stats.max_iterations;
        CHECK(worst <= 1e-5, "%s: %s, reachable vertices off by up to %g of the diagonal", where,
              spia_result_name(r), worst);
    }
    if (r == SPIA_STAGNATED) {
        // A least-squares solution: the normal equations' residual
        // L^T (P - L V) small next to ||L^T|| ||P - L V|| (infinity norms).
        std::vector<double> g((size_t)n * 3, 0.0), column((size_t)n, 0.0);
        double residual = 0.0;
        for (int32_t i = 0; i < n; ++i)
            for (int64_t k = off[(size_t)i]; k < off[(size_t)i + 1]; ++k) {
                const int32_t j = idx[(size_t)k];
                column[(size_t)j] += std::fabs(w[(size_t)k]);
                for (int d = 0; d < 3; ++d) g[3 * (size_t)j + d] += w[(size_t)k] * (P[3 * (size_t)i + d] - LV[3 * (size_t)i + d]);
            }
        for (size_t i = 0; i < P.size(); ++i) residual = std::max(residual, std::fabs(P[i] - LV[i]));
        const double norm_lt = *std::max_element(column.begin(), column.end());
        double gmax = 0.0;
        for (double x : g) gmax = std::max(gmax, std::fabs(x));
        const double ratio = residual > 0.0 ? gmax / (norm_lt * residual) : 0.0;
        stats.worst_lsq = std::max(stats.worst_lsq, ratio);
        CHECK(ratio <= 1e-4, "%s: SPIA_STAGNATED but not a least-squares solution: |L^T (P - L V)| = %g, "
                             "|L^T| |P - L V| = %g (ratio %g)", where, gmax, norm_lt * residual, ratio);
        snprintf(extra, sizeof extra, "  lsq %.1e", ratio);
    }
    printf("%-60s %-28s unreachable %d  worst %.2e  it %d %s%s  [%.2fs %.2fs %.2fs]\n", where, spia_result_name(r),
           (int)set, worst, (int)rep.iterations, extra, reference, t_stencils, t_reference, t_solve);
    spia_stencils_free(s);
}

}  // namespace

// Every configuration of the shape at path; failures go to test_failures.
void run_shape(const std::string &path, bool full, bool sanitized) {
    std::string name = path.substr(path.find_last_of("/\\") + 1);
    if (name.size() > 2 && name.compare(name.size() - 2, 2, ".h") == 0) name.resize(name.size() - 2);

    std::ifstream f(path, std::ios::binary);
    if (!f) {
        CHECK(false, "cannot read %s: %s", path.c_str(), strerror(errno));
        return;
    }
    std::stringstream buffer;
    buffer << f.rdbuf();
    std::string text;
    if (!shape_text(buffer.str(), text)) {
        CHECK(false, "%s: no shape string found", path.c_str());
        return;
    }
    Shape shape;
    parse_obj(text, shape);
    const std::string why = out_of_scope(name, shape);
    CHECK(why.empty(), "%s is out of scope (%s): CMakeLists.txt should not have registered it", name.c_str(),
          why.c_str());
    if (!why.empty()) return;
    CHECK(!shape.verts.empty() && !shape.sizes.empty(), "%s: no vertices or no faces", name.c_str());
    tmesh m;
    std::string error;
    const bool built = build_mesh(shape, m, error);
    CHECK(built, "%s: %s", name.c_str(), error.c_str());
    if (!built) return;
    printf("%s: %d vertices, %d faces, %d creased edges, %d creased vertices\n", name.c_str(), (int)m.nv, (int)m.nf,
           (int)m.ne, m.vertex_creases ? (int)std::count_if(m.vertex_creases, m.vertex_creases + m.nv,
                                                             [](float c) { return c > 0.0f; })
                                       : 0);

    struct Scheme {
        spia_scheme scheme;
        spia_boundary_rule rule;
    };
    std::vector<Scheme> schemes;
    if (name.rfind("catmark_", 0) == 0) {
        schemes = {{SPIA_SCHEME_CATMULL_CLARK, SPIA_BOUNDARY_RULE_SMOOTH}, {SPIA_SCHEME_DOO_SABIN, SPIA_BOUNDARY_RULE_SMOOTH}};
    } else {
        schemes = {{SPIA_SCHEME_LOOP, SPIA_BOUNDARY_RULE_SMOOTH},
                   {SPIA_SCHEME_LOOP, SPIA_BOUNDARY_RULE_HOPPE},
                   {SPIA_SCHEME_CATMULL_CLARK, SPIA_BOUNDARY_RULE_SMOOTH}};
    }
    // Every configuration on one mesh.
    auto run_all = [&](const std::string &label, const tmesh &mesh) {
        std::vector<int> valence((size_t)mesh.nv + 1, 0);
        std::set<std::pair<int, int>> edges;
        int64_t c = 0;
        for (int32_t f = 0; f < mesh.nf; ++f) {
            for (int k = 0; k < mesh.sizes[f]; ++k) {
                const int a = mesh.fv[c + k], b = mesh.fv[c + (k + 1) % mesh.sizes[f]];
                if (edges.insert(std::make_pair(std::min(a, b), std::max(a, b))).second) ++valence[a], ++valence[b];
            }
            c += mesh.sizes[f];
        }
        max_valence = *std::max_element(valence.begin(), valence.end());
        max_reference_quality = !full && max_valence > 100 ? 1 : 10;
        reference_cache.clear();
        loop_reference_cache.clear();
        Stats stats;
        for (const Scheme &sc : schemes)
            for (int preserve = 0; preserve < 2; ++preserve)
                for (int quality : {1, 3, 6}) {
                    // (--sanitized: Loop's smooth rule at quality 3 only; its
                    // semi-sharp creases are refined uniformly, 7 levels
                    // deep on loop_cubes_semisharp, 30 s a table under ASan)
                    if (sanitized && sc.scheme == SPIA_SCHEME_LOOP && sc.rule == SPIA_BOUNDARY_RULE_SMOOTH &&
                        quality != 3)
                        continue;
                    for (int creases = 1; creases >= 0; --creases)
                        run(label, mesh, sc.scheme, sc.rule, preserve != 0, quality, creases != 0, stats);
                }
        printf("%s: %d configurations: %d solved, %d stagnated, %d at max iterations, %d refused; "
               "worst difference from OpenSubdiv's factory %.1e of the diagonal; worst least-squares ratio %.1e\n",
               label.c_str(), stats.configs, stats.ok, stats.stagnated, stats.max_iterations, stats.refused,
               stats.worst_reference, stats.worst_lsq);
    };
    run_all(name, m);
    // The library refuses faces that use a vertex twice (OpenSubdiv takes
    // them): the shape once more without them, as Blender's OBJ importer
    // reads it, creases on edges no face keeps left out.
    tmesh kept;
    memset(&kept, 0, sizeof kept);
    for (int32_t v = 0; v < m.nv; ++v) tmesh_vertex(&kept, m.pos[3 * v], m.pos[3 * v + 1], m.pos[3 * v + 2]);
    for (int32_t f = 0, c = 0; f < m.nf; c += m.sizes[f++]) tmesh_face(&kept, m.sizes[f], m.fv + c);
    drop_degenerate_faces(&kept);
    if (kept.nf < m.nf) {
        std::set<std::pair<int, int>> face_edges;
        for (int32_t f = 0, c = 0; f < kept.nf; c += kept.sizes[f++])
            for (int k = 0; k < kept.sizes[f]; ++k) {
                const int a = kept.fv[c + k], b = kept.fv[c + (k + 1) % kept.sizes[f]];
                face_edges.insert(std::make_pair(std::min(a, b), std::max(a, b)));
            }
        for (int32_t e = 0; e < m.ne; ++e) {
            const int a = m.edges[2 * e], b = m.edges[2 * e + 1];
            if (face_edges.count(std::make_pair(std::min(a, b), std::max(a, b))))
                tmesh_edge(&kept, a, b, m.edge_creases[e]);
        }
        if (m.vertex_creases)
            for (int32_t v = 0; v < m.nv; ++v)
                if (m.vertex_creases[v] > 0.0f) tmesh_vertex_crease(&kept, v, m.vertex_creases[v]);
        printf("%s: %d faces that use a vertex twice left out\n", name.c_str(), (int)(m.nf - kept.nf));
        if (kept.nf > 0) run_all(name + "-nodegen", kept);
    }
    tmesh_free(&kept);
    tmesh_free(&m);
}

int main(int argc, char **argv) {
    bool full = false, sanitized = false;
    std::vector<std::string> paths;
    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        if (arg == "--full")
            full = true;
        else if (arg == "--sanitized")
            sanitized = true, loop_reference_faces = 1 << 17;
        else
            paths.push_back(arg);
    }
    if (paths.empty()) {
        fprintf(stderr, "usage: test_shapes SHAPE.h... [--full] [--sanitized]\n");
        return 2;
    }
    for (const std::string &path : paths) run_shape(path, full, sanitized);
    TEST_MAIN_END();
}
