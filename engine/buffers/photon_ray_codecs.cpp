// Codecs of photon ray splatting's buffers (Herzog et al. 2007): photon rays
// as traced and, with their bandwidths, as splatted, the splat kd-tree over
// the eye vertices and the SH radiance map, so that `render --save` writes them and `--import` /
// `replay --inputs` read them back. Scalars before arrays, as every codec in
// engine/buffers/buffer_codecs.cpp; the kd-tree is saved as built and checked
// structurally on loading (SplatKdTree::restore), never rebuilt, so a loaded
// index visits the same vertices in the same order as the saved one.
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/buffers/radiance_cache_buffers.h"

#include <string>
#include <utility>
#include <vector>

namespace fg {

namespace {

// The scalars PhotonRays and SplatRays share, in the order both files hold them.
template <class Rays>
void writeRayScalars(const Rays& rays, CodecWriter& writer) {
    writer.setItemCount(rays.rays.size());
    writer.write<std::uint64_t>(rays.emitted);
    writer.write<float>(rays.clampDistance);
    for (std::uint64_t count : rays.countPerClass) writer.write<std::uint64_t>(count);
    writer.write<double>(rays.normalisation);
    writer.write<double>(rays.sceneScale);
}

constexpr std::uint64_t kRayScalarBytes =
    sizeof(std::uint64_t) + sizeof(float) + sizeof(std::uint64_t) * PhotonRayClass::Count + 2 * sizeof(double);

template <class Rays>
void readRayScalars(Rays& rays, CodecReader& reader) {
    rays.emitted = reader.read<std::uint64_t>();
    rays.clampDistance = reader.read<float>();
    for (std::uint64_t& count : rays.countPerClass) count = reader.read<std::uint64_t>();
    rays.normalisation = reader.read<double>();
    rays.sceneScale = reader.read<double>();
}

template <class Rays>
void refuseUnknownRayClasses(const Rays& rays, CodecReader& reader) {
    for (std::uint8_t c : rays.rays.template column<RayClassColumn>())
        if (c >= PhotonRayClass::Count) reader.fail("corrupt buffer: photon ray class " + std::to_string(c));
}

}  // namespace

BufferCodec photonRaysCodec() {
    return withScalarBytes(makeBufferCodec<PhotonRays>(
        [](const PhotonRays& rays, CodecWriter& writer) {
            writeRayScalars(rays, writer);
            writer.write(rays.hasBandwidths);
            writer.writeSoa("rays", rays.rays);
        },
        [](CodecReader& reader) {
            PhotonRays rays;
            readRayScalars(rays, reader);
            rays.hasBandwidths = reader.read<bool>();
            reader.readSoa("rays", rays.rays);
            refuseUnknownRayClasses(rays, reader);
            return rays;
        }),
        kRayScalarBytes + 1);
}

BufferCodec splatRaysCodec() {
    return withScalarBytes(makeBufferCodec<SplatRays>(
        [](const SplatRays& rays, CodecWriter& writer) {
            writeRayScalars(rays, writer);
            writer.writeSoa("rays", rays.rays);
        },
        [](CodecReader& reader) {
            SplatRays rays;
            readRayScalars(rays, reader);
            reader.readSoa("rays", rays.rays);
            refuseUnknownRayClasses(rays, reader);
            return rays;
        }),
        kRayScalarBytes);
}

BufferCodec splatIndexCodec() {
    return withScalarBytes(makeBufferCodec<SplatIndex>(
        [](const SplatIndex& index, CodecWriter& writer) {
            const SplatKdTree& tree = index.tree;
            writer.setItemCount(tree.size());
            writer.write<std::uint32_t>(tree.options().maxLeafSize);
            writer.write<float>(tree.options().minCellDiagonal);
            writer.write<float>(tree.options().maxCullDeviationDegrees);
            for (int a = 0; a < 3; ++a) writer.write<float>(tree.boundsMin()[a]);
            for (int a = 0; a < 3; ++a) writer.write<float>(tree.boundsMax()[a]);
            writer.writeVector("nodes", tree.nodes());
            writer.writeVector("ids", tree.ids());
            writer.writeVector("positions", tree.slotPositions());
            writer.writeVector("normals", tree.slotNormals());
        },
        [](CodecReader& reader) {
            SplatKdTreeOptions options;
            options.maxLeafSize = reader.read<std::uint32_t>();
            options.minCellDiagonal = reader.read<float>();
            options.maxCullDeviationDegrees = reader.read<float>();
            Vec3 lo, hi;
            for (int a = 0; a < 3; ++a) lo[a] = reader.read<float>();
            for (int a = 0; a < 3; ++a) hi[a] = reader.read<float>();
            std::vector<SplatKdNode> nodes = reader.readVector<SplatKdNode>("nodes");
            std::vector<std::uint32_t> ids = reader.readVector<std::uint32_t>("ids");
            std::vector<Vec3> positions = reader.readVector<Vec3>("positions");
            std::vector<Vec3> normals = reader.readVector<Vec3>("normals");
            // restore() throws std::invalid_argument on arrays that do not fit
            // together; loadBuffer reports it as a corrupt buffer.
            SplatIndex index;
            index.tree = SplatKdTree::restore(options, lo, hi, std::move(nodes), std::move(ids), std::move(positions),
                                              std::move(normals));
            return index;
        }),
        sizeof(std::uint32_t) + 8 * sizeof(float));
}

BufferCodec radianceMapCodec() {
    return withScalarBytes(makeBufferCodec<RadianceMap>(
        [](const RadianceMap& map, CodecWriter& writer) {
            writer.setItemCount(map.vertices.size());
            writer.writeSoa("vertices", map.vertices);
        },
        [](CodecReader& reader) {
            RadianceMap map;
            reader.readSoa("vertices", map.vertices);
            return map;
        }),
        0);
}

// The records' layout has changed before and may again: files name the
// version they were written with, and others are refused rather than misread.
inline constexpr std::uint32_t kCacheRecordsCodecVersion = 1;

BufferCodec cacheRecordsCodec() {
    return withScalarBytes(makeBufferCodec<CacheRecords>(
        [](const CacheRecords& cache, CodecWriter& writer) {
            writer.setItemCount(cache.records.size());
            writer.write<std::uint32_t>(kCacheRecordsCodecVersion);
            writer.write<float>(cache.error);
            writer.writeSoa("records", cache.records);
        },
        [](CodecReader& reader) {
            CacheRecords cache;
            cache.error = reader.read<float>();
            reader.readSoa("records", cache.records);
            for (float radius : cache.records.column<CacheRadius>())
                if (!(radius > 0.0f)) reader.fail("corrupt buffer: cache record radius " + std::to_string(radius));
            return cache;
        },
        codecVersionCheck(kCacheRecordsCodecVersion, "cache records")),
        sizeof(std::uint32_t) + sizeof(float));
}

}  // namespace fg
