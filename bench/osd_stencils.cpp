// SPDX-License-Identifier: GPL-3.0-or-later
// OpenSubdiv's own limit stencils for every vertex of a mesh, timed, for
// bench/bench_scale.py to set beside the library's.
//
//   spia_bench_osd far|bfr MESH.bin LIMITS.bin [QUALITY]
//
// far: Far::LimitStencilTableFactory on a refiner adaptively isolated to
//      QUALITY (default 3) with infinitely sharp patches, one location per
//      vertex at a corner of a face that uses it (how Blender's modifier
//      evaluates the limit surface with "Use Limit Surface" on).
// bfr: Bfr::RefinerSurfaceFactory, Surface::EvaluateStencil at the same face
//      corners (default Bfr options).
//
// MESH.bin (written by bench_scale.py, little endian):
//   char[8] "SPIAMSH1"; int32 vertices, faces; int64 corners; int32 creased edges;
//   float32 positions[3 * vertices]; int32 face sizes[faces]; int32 face vertices[corners];
//   int32 crease edge ends[2 * creased]; float32 crease[creased] (Blender's 0..1).
// LIMITS.bin receives the limit point of every vertex (float64 x y z), which
// the caller compares with the library's stencils applied to the positions.
// Prints one JSON line: mode, stencils, weights, seconds (topology, refinement
// and stencils; not reading the file) and peak_bytes (VmHWM growth).
#include <opensubdiv/bfr/refinerSurfaceFactory.h>
#include <opensubdiv/bfr/surface.h>
#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

using namespace OpenSubdiv;

namespace {

struct InputMesh {
    int32_t nv = 0, nf = 0, ncrease = 0;
    int64_t ncorners = 0;
    std::vector<float> positions;
    std::vector<int32_t> sizes, verts, crease_ends;
    std::vector<float> creases;
};

template <class T> bool read_array(FILE *f, std::vector<T> &v, int64_t n) {
    v.resize((size_t)n);
    return n == 0 || fread(v.data(), sizeof(T), (size_t)n, f) == (size_t)n;
}

bool read_mesh(const char *path, InputMesh &m) {
    FILE *f = fopen(path, "rb");
    if (!f) return false;
    char magic[8];
    bool ok = fread(magic, 1, 8, f) == 8 && memcmp(magic, "SPIAMSH1", 8) == 0 && fread(&m.nv, 4, 1, f) == 1 &&
              fread(&m.nf, 4, 1, f) == 1 && fread(&m.ncorners, 8, 1, f) == 1 && fread(&m.ncrease, 4, 1, f) == 1;
    ok = ok && read_array(f, m.positions, 3 * (int64_t)m.nv) && read_array(f, m.sizes, m.nf) &&
         read_array(f, m.verts, m.ncorners) && read_array(f, m.crease_ends, 2 * (int64_t)m.ncrease) &&
         read_array(f, m.creases, m.ncrease);
    fclose(f);
    return ok;
}

long status_bytes(const char *field) {
    FILE *f = fopen("/proc/self/status", "r");
    if (!f) return -1;
    char line[256];
    long kb = -1;
    size_t len = strlen(field);
    while (fgets(line, sizeof line, f))
        if (strncmp(line, field, len) == 0) kb = atol(line + len + 1);
    fclose(f);
    return kb * 1024;
}

Far::TopologyRefiner *make_refiner(const InputMesh &m, std::vector<float> &sharpness) {
    Far::TopologyDescriptor desc;
    desc.numVertices = m.nv;
    desc.numFaces = m.nf;
    desc.numVertsPerFace = m.sizes.data();
    desc.vertIndicesPerFace = m.verts.data();
    sharpness.resize(m.creases.size());
    for (size_t e = 0; e < m.creases.size(); ++e) sharpness[e] = m.creases[e] * m.creases[e] * 10.0f;  // Blender's
    desc.numCreases = m.ncrease;
    desc.creaseVertexIndexPairs = m.crease_ends.data();
    desc.creaseWeights = sharpness.data();
    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(Sdc::Options::VTX_BOUNDARY_EDGE_ONLY);
    sdc.SetCreasingMethod(Sdc::Options::CREASE_UNIFORM);
    sdc.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);
    using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
    return Factory::Create(desc, Factory::Options(Sdc::SCHEME_CATMARK, sdc));
}

// For each vertex, one face using it and the corner it is in that face.
void first_corners(const InputMesh &m, std::vector<int32_t> &face, std::vector<int32_t> &corner) {
    face.assign((size_t)m.nv, -1);
    corner.assign((size_t)m.nv, -1);
    int64_t c = 0;
    for (int32_t f = 0; f < m.nf; ++f)
        for (int32_t k = 0; k < m.sizes[f]; ++k, ++c) {
            int32_t v = m.verts[(size_t)c];
            if (face[v] < 0) face[v] = f, corner[v] = k;
        }
}

}  // namespace

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: %s far|bfr MESH.bin LIMITS.bin [QUALITY]\n", argv[0]);
        return 2;
    }
    const std::string mode = argv[1];
    const int quality = argc > 4 ? atoi(argv[4]) : 3;
    InputMesh m;
    if (!read_mesh(argv[2], m)) {
        fprintf(stderr, "cannot read %s\n", argv[2]);
        return 2;
    }
    std::vector<double> limits(3 * (size_t)m.nv, 0.0);
    std::vector<int32_t> vface, vcorner;
    first_corners(m, vface, vcorner);
    FILE *clear = fopen("/proc/self/clear_refs", "w");
    if (clear) fputs("5", clear), fclose(clear);
    const long rss0 = status_bytes("VmRSS:");
    const auto t0 = std::chrono::steady_clock::now();

    std::vector<float> sharpness;
    std::unique_ptr<Far::TopologyRefiner> refiner(make_refiner(m, sharpness));
    if (!refiner) {
        fprintf(stderr, "OpenSubdiv refused the mesh\n");
        return 1;
    }
    long stencils = 0, weights = 0;
    if (mode == "far") {
        Far::TopologyRefiner::AdaptiveOptions adaptive(quality);
        adaptive.useInfSharpPatch = true;
        refiner->RefineAdaptive(adaptive);
        Far::PtexIndices ptex(*refiner);
        static const float qs[4] = {0, 1, 1, 0}, qt[4] = {0, 0, 1, 1};
        static const float zero = 0.0f;
        Far::LimitStencilTableFactory::LocationArrayVec locations;
        std::vector<int32_t> location_vertex;
        for (int32_t v = 0; v < m.nv; ++v) {
            if (vface[v] < 0) continue;
            Far::LimitStencilTableFactory::LocationArray loc;
            loc.numLocations = 1;
            if (m.sizes[vface[v]] == 4) {
                loc.ptexIdx = ptex.GetFaceId(vface[v]);
                loc.s = &qs[vcorner[v]];
                loc.t = &qt[vcorner[v]];
            } else {  // one ptex quad per corner; the vertex is its (0, 0)
                loc.ptexIdx = ptex.GetFaceId(vface[v]) + vcorner[v];
                loc.s = loc.t = &zero;
            }
            locations.push_back(loc);
            location_vertex.push_back(v);
        }
        Far::LimitStencilTableFactory::Options options;
        options.generate1stDerivatives = false;
        std::unique_ptr<const Far::LimitStencilTable> table(
            Far::LimitStencilTableFactory::Create(*refiner, locations, nullptr, nullptr, options));
        if (!table) {
            fprintf(stderr, "no limit stencil table\n");
            return 1;
        }
        stencils = table->GetNumStencils();
        weights = (long)table->GetControlIndices().size();
        const auto &sizes = table->GetSizes();
        const auto &offsets = table->GetOffsets();
        const auto &idx = table->GetControlIndices();
        const auto &w = table->GetWeights();
        for (long s = 0; s < stencils; ++s) {
            double *out = &limits[3 * (size_t)location_vertex[(size_t)s]];
            for (int k = 0; k < sizes[(size_t)s]; ++k) {
                const size_t e = (size_t)offsets[(size_t)s] + (size_t)k;
                const float *p = &m.positions[3 * (size_t)idx[e]];
                for (int a = 0; a < 3; ++a) out[a] += (double)w[e] * p[a];
            }
        }
    } else if (mode == "bfr") {
        Bfr::RefinerSurfaceFactory<>::Options options;
        Bfr::RefinerSurfaceFactory<> factory(*refiner, options);
        Bfr::Surface<double> surface;
        std::vector<int32_t> cvs;
        std::vector<double> sp;
        // Vertices grouped by the face that evaluates them.
        std::vector<int32_t> count((size_t)m.nf + 1, 0), order((size_t)m.nv);
        for (int32_t v = 0; v < m.nv; ++v)
            if (vface[v] >= 0) count[(size_t)vface[v] + 1]++;
        for (int32_t f = 0; f < m.nf; ++f) count[(size_t)f + 1] += count[(size_t)f];
        std::vector<int32_t> fill(count.begin(), count.end() - 1);
        for (int32_t v = 0; v < m.nv; ++v)
            if (vface[v] >= 0) order[(size_t)fill[(size_t)vface[v]]++] = v;
        for (int32_t f = 0; f < m.nf; ++f) {
            if (count[(size_t)f] == count[(size_t)f + 1]) continue;
            if (!factory.InitVertexSurface(f, &surface) || !surface.IsValid()) {
                fprintf(stderr, "no Bfr surface for face %d\n", f);
                return 1;
            }
            const int n = surface.GetNumControlPoints();
            cvs.resize((size_t)n);
            sp.resize((size_t)n);
            surface.GetControlPointIndices(cvs.data());
            const Bfr::Parameterization param = surface.GetParameterization();
            for (int32_t i = count[(size_t)f]; i < count[(size_t)f + 1]; ++i) {
                const int32_t v = order[(size_t)i];
                double uv[2];
                param.GetVertexCoord(vcorner[v], uv);
                surface.EvaluateStencil(uv, sp.data());
                double *out = &limits[3 * (size_t)v];
                for (int k = 0; k < n; ++k) {
                    const float *p = &m.positions[3 * (size_t)cvs[(size_t)k]];
                    for (int a = 0; a < 3; ++a) out[a] += sp[(size_t)k] * p[a];
                }
                ++stencils;
                weights += n;
            }
        }
    } else {
        fprintf(stderr, "unknown mode %s\n", mode.c_str());
        return 2;
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const long peak = status_bytes("VmHWM:") - rss0;
    FILE *out = fopen(argv[3], "wb");
    if (!out || fwrite(limits.data(), sizeof(double), limits.size(), out) != limits.size()) {
        fprintf(stderr, "cannot write %s\n", argv[3]);
        return 1;
    }
    fclose(out);
    printf("{\"mode\": \"%s\", \"stencils\": %ld, \"weights\": %ld, \"seconds\": %.6f, \"peak_bytes\": %ld}\n",
           mode.c_str(), stencils, weights, seconds, peak);
    return 0;
}
