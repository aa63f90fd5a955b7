// Codecs of the engine's buffer types, so that any buffer a pipeline makes can
// be saved and loaded again (engine/core/codec.h). Each writes every scalar
// member of its buffer before its arrays; the acceleration structures are
// saved as built and checked structurally on loading (their restore()
// functions), never rebuilt, so a loaded index answers queries bit for bit as
// the saved one did.
#include "engine/accel/photon_bvh.h"
#include "engine/accel/point_index.h"
#include "engine/buffers/beam_buffers.h"
#include "engine/buffers/film_noise.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/buffers/radiance_cache_buffers.h"
#include "engine/core/codec.h"
#include "engine/gmm/gmm_buffers.h"
#include "engine/guiding/environment_guide.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/guiding/importons.h"
#include "engine/image/film.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

namespace fg {

namespace {

// Passes divide by the sample count; a corrupt one must fail on loading.
int readSamplesPerPixel(CodecReader& reader) {
    const auto samplesPerPixel = reader.read<std::int32_t>();
    if (samplesPerPixel < 1) reader.fail("corrupt buffer: " + std::to_string(samplesPerPixel) + " samples per pixel");
    return samplesPerPixel;
}

BufferCodec filmCodec() {
    BufferCodec codec = makeBufferCodec<Film>(
        [](const Film& film, CodecWriter& writer) {
            const FilmSettings& settings = film.settings();
            writer.setItemCount(film.pixelCount());
            writer.write<std::int32_t>(settings.width);
            writer.write<std::int32_t>(settings.height);
            writer.write<std::uint32_t>(settings.filter == FilterKind::Gaussian ? 1 : settings.filter == FilterKind::Tent ? 2 : 0);
            writer.write(settings.filterRadius);
            writer.write(settings.gaussianSigma);
            writer.write(film.hasDirect());
            writer.writeVector("weighted_sum", film.weightedSums());
            writer.writeVector("weight_sum", film.weightSums());
            writer.writeVector("direct", film.directSums());
            writer.write(static_cast<std::uint32_t>(film.aovs().size()));
            for (const auto& [name, values] : film.aovs()) {
                writer.writeString(name);
                writer.writeVector("aov." + name, values);
            }
        },
        [](CodecReader& reader) {
            FilmSettings settings;
            settings.width = reader.read<std::int32_t>();
            settings.height = reader.read<std::int32_t>();
            const auto filter = reader.read<std::uint32_t>();
            if (filter > 2) reader.fail("corrupt buffer: filter kind " + std::to_string(filter));
            settings.filter = filter == 1 ? FilterKind::Gaussian : filter == 2 ? FilterKind::Tent : FilterKind::Box;
            settings.filterRadius = reader.read<float>();
            settings.gaussianSigma = reader.read<float>();
            const bool hasDirect = reader.read<bool>();
            std::vector<Rgb> weightedSums = reader.readVector<Rgb>("weighted_sum");
            std::vector<float> weightSums = reader.readVector<float>("weight_sum");
            std::vector<Rgb> direct = reader.readVector<Rgb>("direct");
            const auto aovCount = reader.read<std::uint32_t>();
            // Each AOV is a column, and the header holds no more columns than the file can.
            if (aovCount > reader.columns().size())
                reader.fail("corrupt buffer: " + std::to_string(aovCount) + " AOVs");
            std::vector<std::pair<std::string, std::vector<float>>> aovs;
            for (std::uint32_t i = 0; i < aovCount; ++i) {
                std::string name = reader.readString();
                std::vector<float> values = reader.readVector<float>("aov." + name);
                aovs.emplace_back(std::move(name), std::move(values));
            }
            return Film::restore(settings, std::move(weightedSums), std::move(weightSums), std::move(direct),
                                 hasDirect, std::move(aovs));
        });
    // Size, filter, radius, sigma, the direct flag, the AOV count and each
    // AOV's name, which its column's name repeats after "aov.".
    codec.scalarBytes = [](std::span<const CodecColumn> columns) {
        std::uint64_t bytes = 5 * sizeof(std::int32_t) + 1 + sizeof(std::uint32_t);
        for (const CodecColumn& column : columns)
            if (column.name.rfind("aov.", 0) == 0) bytes += sizeof(std::uint32_t) + column.name.size() - 4;
        return bytes;
    };
    return codec;
}

BufferCodec photonMapCodec() {
    return withScalarBytes(makeBufferCodec<PhotonMap>(
        [](const PhotonMap& map, CodecWriter& writer) {
            writer.setItemCount(map.photons.size());
            writer.write<std::uint64_t>(map.emitted);
            writer.write<std::uint64_t>(map.collapsedFootprints);
            writer.write(map.hasDifferentials);
            writer.writeSoa("photons", map.photons);
        },
        [](CodecReader& reader) {
            PhotonMap map;
            map.emitted = reader.read<std::uint64_t>();
            map.collapsedFootprints = reader.read<std::uint64_t>();
            map.hasDifferentials = reader.read<bool>();
            reader.readSoa("photons", map.photons);
            return map;
        }),
        2 * sizeof(std::uint64_t) + 1);
}

BufferCodec volumePhotonMapCodec() {
    return withScalarBytes(makeBufferCodec<VolumePhotonMap>(
        [](const VolumePhotonMap& map, CodecWriter& writer) {
            writer.setItemCount(map.photons.size());
            writer.write<std::uint64_t>(map.emitted);
            writer.writeSoa("photons", map.photons);
        },
        [](CodecReader& reader) {
            VolumePhotonMap map;
            map.emitted = reader.read<std::uint64_t>();
            reader.readSoa("photons", map.photons);
            return map;
        }),
        sizeof(std::uint64_t));
}

BufferCodec filmNoiseCodec() {
    return withScalarBytes(makeBufferCodec<FilmNoise>(
        [](const FilmNoise& noise, CodecWriter& writer) {
            writer.setItemCount(noise.mean.size());
            writer.write<std::int64_t>(noise.batches);
            writer.write<double>(noise.relativeError);
            writer.writeVector("previous_sums", noise.previousSums);
            writer.writeVector("previous_weights", noise.previousWeights);
            writer.writeVector("mean", noise.mean);
            writer.writeVector("m2", noise.m2);
        },
        [](CodecReader& reader) {
            FilmNoise noise;
            noise.batches = reader.read<std::int64_t>();
            noise.relativeError = reader.read<double>();
            noise.previousSums = reader.readVector<Rgb>("previous_sums");
            noise.previousWeights = reader.readVector<float>("previous_weights");
            noise.mean = reader.readVector<double>("mean");
            noise.m2 = reader.readVector<double>("m2");
            const std::size_t pixels = noise.mean.size();
            if (noise.previousSums.size() != pixels || noise.previousWeights.size() != pixels || noise.m2.size() != pixels)
                reader.fail("FilmNoise columns disagree in length");
            return noise;
        }),
        sizeof(std::int64_t) + sizeof(double));
}

BufferCodec eyeVerticesCodec() {
    return withScalarBytes(makeBufferCodec<EyeVertices>(
        [](const EyeVertices& eye, CodecWriter& writer) {
            writer.setItemCount(eye.vertices.size());
            writer.write<std::int32_t>(eye.samplesPerPixel);
            writer.writeSoa("vertices", eye.vertices);
        },
        [](CodecReader& reader) {
            EyeVertices eye;
            eye.samplesPerPixel = readSamplesPerPixel(reader);
            reader.readSoa("vertices", eye.vertices);
            return eye;
        }),
        sizeof(std::int32_t));
}

BufferCodec photonRadiiCodec() {
    return withScalarBytes(makeBufferCodec<PhotonRadii>(
        [](const PhotonRadii& radii, CodecWriter& writer) {
            writer.setItemCount(radii.radii.size());
            writer.write<std::uint32_t>(radii.neighbours);
            writer.write<float>(radii.scale);
            writer.writeSoa("radii", radii.radii);
        },
        [](CodecReader& reader) {
            PhotonRadii radii;
            radii.neighbours = reader.read<std::uint32_t>();
            radii.scale = reader.read<float>();
            reader.readSoa("radii", radii.radii);
            return radii;
        }),
        sizeof(std::uint32_t) + sizeof(float));
}

BufferCodec eyeSegmentsCodec() {
    return withScalarBytes(makeBufferCodec<EyeSegments>(
        [](const EyeSegments& segments, CodecWriter& writer) {
            writer.setItemCount(segments.segments.size());
            writer.write<std::int32_t>(segments.samplesPerPixel);
            writer.writeSoa("segments", segments.segments);
        },
        [](CodecReader& reader) {
            EyeSegments segments;
            segments.samplesPerPixel = readSamplesPerPixel(reader);
            reader.readSoa("segments", segments.segments);
            return segments;
        }),
        sizeof(std::int32_t));
}

BufferCodec pointIndexCodec() {
    return withScalarBytes(makeBufferCodec<PointIndex>(
        [](const PointIndex& index, CodecWriter& writer) {
            const KdTree& tree = index.tree();
            writer.setItemCount(index.size());
            writer.write<std::uint32_t>(tree.maxLeafSize());
            writer.writeVector("ids", index.ids());
            writer.writeVector("tree.positions", tree.sortedPositions());
            writer.writeVector("tree.permutation", tree.permutation());
            writer.writeVector("tree.splits", tree.splits());
        },
        [](CodecReader& reader) {
            const auto leafSize = reader.read<std::uint32_t>();
            std::vector<std::uint32_t> ids = reader.readVector<std::uint32_t>("ids");
            std::vector<Vec3> positions = reader.readVector<Vec3>("tree.positions");
            std::vector<std::uint32_t> permutation = reader.readVector<std::uint32_t>("tree.permutation");
            std::vector<KdTree::Split> splits = reader.readVector<KdTree::Split>("tree.splits");
            return PointIndex::restore(
                KdTree::restore(std::move(positions), std::move(permutation), std::move(splits), leafSize),
                std::move(ids));
        }),
        sizeof(std::uint32_t));
}

BufferCodec photonBvhCodec() {
    return withScalarBytes(makeBufferCodec<PhotonBvh>(
        [](const PhotonBvh& bvh, CodecWriter& writer) {
            writer.setItemCount(bvh.size());
            writer.write<std::uint32_t>(bvh.depth());
            writer.writeSoa("nodes", bvh.nodes());
            writer.writeSoa("spheres", bvh.spheres());
        },
        [](CodecReader& reader) {
            const auto depth = reader.read<std::uint32_t>();
            BvhNodeBuffer nodes;
            BvhSphereBuffer spheres;
            reader.readSoa("nodes", nodes);
            reader.readSoa("spheres", spheres);
            return PhotonBvh::restore(std::move(nodes), std::move(spheres), depth);
        }),
        sizeof(std::uint32_t));
}

// A loaded mixture is used for sampling at once: every component must be a
// usable Gaussian, with the derived terms finalize() would give it.
bool validMixture(const DirectionalGmm& gmm) {
    for (const GmmComponent& c : gmm.components) {
        const float det = c.covXX * c.covYY - c.covXY * c.covXY;
        const float values[] = {c.weight, c.mean.x, c.mean.y, c.covXX, c.covXY, c.covYY, c.invXX, c.invXY,
                                c.invYY, c.normalisation, c.cholXX, c.cholYX, c.cholYY};
        for (float v : values)
            if (!std::isfinite(v)) return false;
        if (c.weight < 0.0f || (c.weight > 0.0f && !(det > 0.0f && c.covXX > 0.0f))) return false;
    }
    // The evaluation lanes are derived too, and sampling indexes components by
    // the cdf lane: they must be what finalize() derives from these components
    // (to rounding, since it renormalises the weights once more).
    DirectionalGmm derived = gmm;
    if (derived.finalize() != gmm.usable()) return false;
    const auto close = [](const GmmLanes::Lanes& a, const GmmLanes::Lanes& b) {
        for (int j = 0; j < kGmmComponents; ++j) {
            if (a[j] == b[j]) continue;
            if (!(std::abs(a[j] - b[j]) <= 1e-4f * std::max(std::abs(a[j]), std::abs(b[j])) + 1e-30f)) return false;
        }
        return true;
    };
    const GmmLanes& a = gmm.lanes;
    const GmmLanes& b = derived.lanes;
    return close(a.cdf, b.cdf) && close(a.meanX, b.meanX) && close(a.meanY, b.meanY) && close(a.cholXX, b.cholXX) &&
           close(a.cholYX, b.cholYX) && close(a.cholYY, b.cholYY) && close(a.quadXX, b.quadXX) &&
           close(a.quadXY, b.quadXY) && close(a.quadYY, b.quadYY) && close(a.scale, b.scale);
}

BufferCodec importonMapCodec() {
    return withScalarBytes(makeBufferCodec<ImportonMap>(
        [](const ImportonMap& map, CodecWriter& writer) {
            writer.setItemCount(map.importons.size());
            writer.write<std::uint64_t>(map.paths);
            writer.writeSoa("importons", map.importons);
        },
        [](CodecReader& reader) {
            ImportonMap map;
            map.paths = reader.read<std::uint64_t>();
            reader.readSoa("importons", map.importons);
            return map;
        }),
        sizeof(std::uint64_t));
}

BufferCodec importonExitsCodec() {
    return withScalarBytes(makeBufferCodec<ImportonExits>(
        [](const ImportonExits& exits, CodecWriter& writer) {
            writer.setItemCount(exits.exits.size());
            writer.write<std::uint64_t>(exits.paths);
            writer.writeSoa("exits", exits.exits);
        },
        [](CodecReader& reader) {
            ImportonExits exits;
            exits.paths = reader.read<std::uint64_t>();
            reader.readSoa("exits", exits.exits);
            return exits;
        }),
        sizeof(std::uint64_t));
}

// The environment sampler (Vorba et al. 2014, §4.4) is trained across passes
// like the caches, so it is saved and imported like them: its codec version
// first, then the bitmap's layout, the bounding sphere the disks sit on, the
// training state, and one cell per bitmap pixel. A loaded model must be
// usable: a layout matching the cells, finite densities, valid mixtures.
constexpr std::uint32_t kEnvironmentGuideCodecVersion = 1;
constexpr std::uint64_t kEnvironmentGuideScalarBytes =
    3 * sizeof(std::uint32_t) + 4 * sizeof(float) + sizeof(std::uint64_t) + sizeof(float);

BufferCodec environmentGuideCodec() {
    return withScalarBytes(makeBufferCodec<EnvironmentGuide>(
        [](const EnvironmentGuide& guide, CodecWriter& writer) {
            writer.setItemCount(guide.cells.size());
            writer.write<std::uint32_t>(kEnvironmentGuideCodecVersion);
            writer.write<std::uint32_t>(guide.columns);
            writer.write<std::uint32_t>(guide.rows);
            writer.write(guide.center.x);
            writer.write(guide.center.y);
            writer.write(guide.center.z);
            writer.write(guide.radius);
            writer.write<std::uint64_t>(guide.passes);
            writer.write(guide.kernelCap);
            writer.writeSoa("cells", guide.cells);
        },
        [](CodecReader& reader) {
            EnvironmentGuide guide;
            guide.columns = reader.read<std::uint32_t>();
            guide.rows = reader.read<std::uint32_t>();
            guide.center.x = reader.read<float>();
            guide.center.y = reader.read<float>();
            guide.center.z = reader.read<float>();
            guide.radius = reader.read<float>();
            guide.passes = reader.read<std::uint64_t>();
            guide.kernelCap = reader.read<float>();
            reader.readSoa("cells", guide.cells);
            if (guide.cells.size() != guide.cellCount() || (guide.cellCount() > 0 && !(guide.radius > 0.0f)))
                reader.fail("corrupt buffer: an environment sampler of " + std::to_string(guide.cells.size()) +
                            " cells for a " + std::to_string(guide.columns) + " x " + std::to_string(guide.rows) +
                            " bitmap");
            const auto density = guide.cells.column<EnvCellDensity>();
            const auto gmms = guide.cells.column<EnvCellMixture>();
            const auto fitted = guide.cells.column<EnvCellFitted>();
            for (std::size_t i = 0; i < guide.cells.size(); ++i)
                if (!std::isfinite(density[i]) || !(density[i] >= 0.0f) || (fitted[i] != 0 && !validMixture(gmms[i])))
                    reader.fail("corrupt buffer: environment sampler cell " + std::to_string(i));
            return guide;
        },
        codecVersionCheck(kEnvironmentGuideCodecVersion, "an environment sampler")),
        kEnvironmentGuideScalarBytes);
}

// The guiding cache's records gain columns as guiding does (bsdf_only and
// moment_ratio were added to the first layout), so its payload begins with
// its codec version and other versions are refused rather than misread.
// Versions 1 and 2 are the two layouts saved before the version was written:
// 1 without bsdf_only and moment_ratio, 2 with them. Neither holds a version
// to read, but the payload's size tells them from a versioned file: their
// scalars (training passes, leaf size) are 12 bytes besides the columns, a
// versioned file's 16.
constexpr std::uint32_t kGuidingCacheCodecVersion = 3;
constexpr std::uint64_t kGuidingCacheScalarBytes = sizeof(std::uint32_t) + sizeof(std::uint64_t) + sizeof(std::uint32_t);

void checkGuidingCacheVersion(CodecReader& reader) {
    const auto what = [](std::uint32_t version) {
        return "a guiding cache of codec version " + std::to_string(version) + " (this build reads version " +
               std::to_string(kGuidingCacheCodecVersion) + ")";
    };
    if (reader.remaining() == reader.columnBytes() + kGuidingCacheScalarBytes - sizeof(std::uint32_t)) {
        const auto& columns = reader.columns();
        const bool decided = std::any_of(columns.begin(), columns.end(),
                                         [](const CodecColumn& c) { return c.name == "records.bsdf_only"; });
        // These were written by earlier builds of this one, so their owners
        // are told how to get a readable file.
        reader.fail(what(decided ? 2 : 1) + ", saved before the version was written: train and save it again with "
                                            "this build");
    }
    const auto version = reader.read<std::uint32_t>();
    if (version != kGuidingCacheCodecVersion) reader.fail(what(version));
}

BufferCodec guidingCacheCodec() {
    BufferCodec codec = makeBufferCodec<GuidingCache>(
        [](const GuidingCache& cache, CodecWriter& writer) {
            const KdTree& tree = cache.tree();
            writer.setItemCount(cache.records.size());
            writer.write<std::uint32_t>(kGuidingCacheCodecVersion);
            writer.write<std::uint64_t>(cache.trainingPasses);
            writer.writeSoa("records", cache.records);
            writer.write<std::uint32_t>(tree.maxLeafSize());
            writer.writeVector("tree.positions", tree.sortedPositions());
            writer.writeVector("tree.permutation", tree.permutation());
            writer.writeVector("tree.splits", tree.splits());
        },
        [](CodecReader& reader) {
            GuidingCache cache;
            cache.trainingPasses = reader.read<std::uint64_t>();
            reader.readSoa("records", cache.records);
            const auto leafSize = reader.read<std::uint32_t>();
            std::vector<Vec3> positions = reader.readVector<Vec3>("tree.positions");
            std::vector<std::uint32_t> permutation = reader.readVector<std::uint32_t>("tree.permutation");
            std::vector<KdTree::Split> splits = reader.readVector<KdTree::Split>("tree.splits");
            if (permutation.size() != cache.records.size())
                reader.fail("corrupt buffer: an index over " + std::to_string(permutation.size()) + " of " +
                            std::to_string(cache.records.size()) + " guiding records");
            // The index must be over these records: a query's ids pick their GMMs.
            const auto recordPositions = cache.records.column<GuidePosition>();
            for (std::size_t k = 0; k < permutation.size(); ++k)
                if (permutation[k] >= recordPositions.size() || positions[k] != recordPositions[permutation[k]])
                    reader.fail("corrupt buffer: the guiding index does not match the records");
            cache.restoreIndex(KdTree::restore(std::move(positions), std::move(permutation), std::move(splits), leafSize));
            const auto radii = cache.records.column<GuideValidityRadius>();
            const auto normals = cache.records.column<GuideNormal>();
            const auto gmms = cache.records.column<GuideMixture>();
            for (std::size_t i = 0; i < cache.records.size(); ++i) {
                const float length = glm::length(normals[i]);
                if (!(std::abs(length - 1.0f) < 1e-3f) || !(radii[i] >= 0.0f) || !std::isfinite(radii[i]) ||
                    !validMixture(gmms[i]))
                    reader.fail("corrupt buffer: guiding record " + std::to_string(i));
            }
            cache.buildCoverGrid();
            return cache;
        },
        checkGuidingCacheVersion);
    return withScalarBytes(std::move(codec), kGuidingCacheScalarBytes);
}

// The fitted Gaussian mixture of pem_fit and em_fit (Jakob et al. 2011 §5),
// saved so that the next frame of an animation can seed its fit with it
// (§5.4). Its codec version is the first scalar, so that a later layout is
// refused rather than misread. Version 2 writes the stored form of
// GmmStoredBuffer (13 parameters and n_eff as floats, 56 bytes per Gaussian)
// and expands it on loading as the fits do, so the loaded mixture equals
// the saved one bit for bit; version 1 wrote every column in doubles,
// derived ones included (216 bytes per Gaussian). A loaded mixture must be
// usable: finite values, a non-negative weight, a positive Cholesky diagonal.
constexpr std::uint32_t kGaussianMixtureCodecVersion = 2;

template <class Buffer>
bool validGaussianComponent(const Buffer& components, std::size_t s) {
    const gmm::Gaussian g = gaussianAt(components, s);
    const double weight = components.template column<GmmWeight>()[s];
    const glm::dvec3 power = components.template column<GmmPower>()[s];
    std::vector<double> values = {weight, components.template column<GmmEffectiveCount>()[s], g.factors.logNormaliser,
                                  power.x, power.y, power.z, g.mean.x, g.mean.y, g.mean.z};
    for (const gmm::Sym3* m : {&g.covariance, &g.factors.cholesky, &g.factors.precision})
        values.insert(values.end(), std::begin(m->v), std::end(m->v));
    for (const double v : values)
        if (!std::isfinite(v)) return false;
    const gmm::Sym3& l = g.factors.cholesky;
    return weight >= 0.0 && l.v[0] > 0.0 && l.v[3] > 0.0 && l.v[5] > 0.0;
}

BufferCodec gaussianMixtureCodec() {
    return withScalarBytes(makeBufferCodec<GaussianMixture>(
        [](const GaussianMixture& mixture, CodecWriter& writer) {
            const GmmBuffer& components = mixture.components;
            GmmStoredBuffer stored(components.size());
            for (std::size_t s = 0; s < components.size(); ++s) stored.set(s, storedComponent(components, s));
            writer.setItemCount(components.size());
            writer.write<std::uint32_t>(kGaussianMixtureCodecVersion);
            writer.write<std::uint64_t>(mixture.photons);
            writer.writeSoa("components", writer.own(std::move(stored)));
        },
        [](CodecReader& reader) {
            GaussianMixture mixture;
            mixture.photons = reader.read<std::uint64_t>();
            GmmStoredBuffer stored;
            reader.readSoa("components", stored);
            mixture.components.resize(stored.size());
            for (std::size_t s = 0; s < stored.size(); ++s)
                if (!expandStoredComponent(stored.get(s), mixture.components, s))
                    reader.fail("corrupt buffer: Gaussian component " + std::to_string(s));
            return mixture;
        },
        [](CodecReader& reader) {
            const auto version = reader.read<std::uint32_t>();
            // Version 1 files were written by earlier builds of this one, so
            // their owners are told how to get a readable file.
            if (version == 1)
                reader.fail("a Gaussian mixture in the layout of codec version 1 (doubles with derived columns); this "
                            "build reads version 2 (floats): fit and save it again with this build");
            if (version != kGaussianMixtureCodecVersion)
                reader.fail("a Gaussian mixture of codec version " + std::to_string(version) +
                            " (this build reads version " + std::to_string(kGaussianMixtureCodecVersion) + ")");
        }),
        sizeof(std::uint32_t) + sizeof(std::uint64_t));
}

// The Gaussian pyramid (Alg. 3) and its bounding hierarchy (§7.1), saved so
// that `replay` can feed gmm_render or gmm_splat and a pyramid can be
// imported. The renderers walk the pyramid by index, so the file must hold a
// depth-first binary tree (left child next, right child further on, leaves
// at level 0, parents above their children) and a BBH of finite boxes.
constexpr std::uint32_t kGmmPyramidCodecVersion = 1;
constexpr std::uint32_t kGmmBbhCodecVersion = 1;

std::string pyramidDefect(const GmmPyramid& pyramid) {
    const std::size_t n = pyramid.nodes.size();
    if (n == 0) return {};
    if (n % 2 == 0) return "a binary pyramid has an odd number of nodes, not " + std::to_string(n);
    const auto right = pyramid.nodes.column<GmmRight>();
    const auto level = pyramid.nodes.column<GmmLevel>();
    for (std::size_t j = 0; j < n; ++j) {
        if (!validGaussianComponent(pyramid.nodes, j)) return "pyramid node " + std::to_string(j) + " is not a usable Gaussian";
        if (level[j] > pyramid.levels) return "pyramid node " + std::to_string(j) + " lies above the top level";
        if (right[j] == kNoGmmNode) {
            if (level[j] != 0) return "pyramid leaf " + std::to_string(j) + " is not at level 0";
            continue;
        }
        if (!(right[j] > j + 1 && right[j] < n)) return "pyramid node " + std::to_string(j) + " has its children out of order";
        if (!(level[j + 1] < level[j] && level[right[j]] < level[j]))
            return "pyramid node " + std::to_string(j) + " is not above its children";
    }
    return {};
}

BufferCodec gmmPyramidCodec() {
    return withScalarBytes(makeBufferCodec<GmmPyramid>(
        [](const GmmPyramid& pyramid, CodecWriter& writer) {
            writer.setItemCount(pyramid.nodes.size());
            writer.write<std::uint32_t>(kGmmPyramidCodecVersion);
            writer.write<std::uint32_t>(pyramid.levels);
            writer.writeSoa("nodes", pyramid.nodes);
        },
        [](CodecReader& reader) {
            GmmPyramid pyramid;
            pyramid.levels = reader.read<std::uint32_t>();
            reader.readSoa("nodes", pyramid.nodes);
            if (const std::string defect = pyramidDefect(pyramid); !defect.empty()) reader.fail("corrupt buffer: " + defect);
            return pyramid;
        },
        codecVersionCheck(kGmmPyramidCodecVersion, "a Gaussian pyramid")),
        2 * sizeof(std::uint32_t));
}

BufferCodec gmmBbhCodec() {
    return withScalarBytes(makeBufferCodec<GmmBbh>(
        [](const GmmBbh& bbh, CodecWriter& writer) {
            writer.setItemCount(bbh.nodes.size());
            writer.write<std::uint32_t>(kGmmBbhCodecVersion);
            writer.write<double>(bbh.truncation);
            writer.writeSoa("nodes", bbh.nodes);
        },
        [](CodecReader& reader) {
            GmmBbh bbh;
            bbh.truncation = reader.read<double>();
            if (!(bbh.truncation > 0.0 && bbh.truncation < 1.0))
                reader.fail("corrupt buffer: a BBH truncation of " + std::to_string(bbh.truncation));
            reader.readSoa("nodes", bbh.nodes);
            const auto lo = bbh.nodes.column<BbhLo>();
            const auto hi = bbh.nodes.column<BbhHi>();
            const auto sphere = bbh.nodes.column<BbhSphere>();
            const auto radius = bbh.nodes.column<BbhRadius>();
            for (std::size_t j = 0; j < bbh.nodes.size(); ++j) {
                const bool finite = std::isfinite(radius[j]) && radius[j] >= 0.0 && std::isfinite(sphere[j].w) &&
                                    sphere[j].w >= 0.0;
                bool ordered = true;
                for (int a = 0; a < 3; ++a)
                    ordered = ordered && std::isfinite(lo[j][a]) && std::isfinite(hi[j][a]) && lo[j][a] <= hi[j][a] &&
                              std::isfinite(sphere[j][a]);
                if (!finite || !ordered) reader.fail("corrupt buffer: BBH node " + std::to_string(j));
            }
            return bbh;
        },
        codecVersionCheck(kGmmBbhCodecVersion, "a Gaussian BBH")),
        sizeof(std::uint32_t) + sizeof(double));
}

}  // namespace

std::vector<BufferCodec> builtinCodecs() {
    std::vector<BufferCodec> codecs;
    codecs.push_back(filmCodec());
    codecs.push_back(photonMapCodec());
    codecs.push_back(volumePhotonMapCodec());
    codecs.push_back(filmNoiseCodec());
    codecs.push_back(eyeVerticesCodec());
    codecs.push_back(photonRadiiCodec());
    codecs.push_back(eyeSegmentsCodec());
    codecs.push_back(pointIndexCodec());
    codecs.push_back(photonBvhCodec());
    codecs.push_back(guidingCacheCodec());
    codecs.push_back(importonMapCodec());
    codecs.push_back(importonExitsCodec());
    codecs.push_back(environmentGuideCodec());
    codecs.push_back(photonRaysCodec());
    codecs.push_back(splatRaysCodec());
    codecs.push_back(splatIndexCodec());
    codecs.push_back(radianceMapCodec());
    codecs.push_back(cacheRecordsCodec());
    codecs.push_back(gaussianMixtureCodec());
    codecs.push_back(gmmPyramidCodec());
    codecs.push_back(gmmBbhCodec());
    return codecs;
}

}  // namespace fg
