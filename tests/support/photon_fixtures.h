// Synthetic photon maps and eye vertices for the density-estimation tests,
// and a stand-in `photon` pass that hands such maps to a pipeline.
#pragma once

#include "engine/shading/bsdf.h"
#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/scene/scene.h"
#include "engine/shading/texture.h"
#include "jobs/random.h"

#include <functional>
#include <memory>

namespace fg::test {

// The albedo of diffuseScene()'s one BSDF.
inline const Rgb kAlbedo(0.7f, 0.5f, 0.3f);

// A scene with one diffuse BSDF (index 0) and no geometry: the density
// estimates only evaluate BSDFs at given eye vertices.
inline Scene diffuseScene() {
    Scene scene;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(kAlbedo)));
    return scene;
}

inline FilmSettings film(int width, int height) {
    FilmSettings f;
    f.width = width;
    f.height = height;
    return f;
}

// Appends one photon (differentials default to zero) and returns its index.
inline std::size_t addPhoton(PhotonMap& map, const Vec3& position, const Vec3& incident, const Rgb& power,
                             const Vec3& normal = Vec3(0, 0, 1), std::uint8_t photonClass = PhotonClass::Global,
                             const Vec3& du = Vec3(0.0f), const Vec3& dv = Vec3(0.0f)) {
    return map.photons.append(PhotonBuffer::Record{position, incident, power, normal, photonClass, du, dv});
}

// Appends one volume photon and returns its index.
inline std::size_t addVolumePhoton(VolumePhotonMap& map, const Vec3& position, const Vec3& incident, const Rgb& power,
                                   std::uint8_t photonClass = PhotonClass::Volume) {
    return map.photons.append(VolumePhotonBuffer::Record{position, incident, power, photonClass});
}

// n photons uniformly on the square [-half, half]^2 of the plane z = 0, arriving
// from cosine-distributed directions, carrying together irradiance E (per channel).
inline void addUniformPlanePhotons(PhotonMap& map, std::size_t n, float half, const Rgb& irradiance,
                                   std::uint8_t photonClass, std::uint64_t seed) {
    const Rgb power = irradiance * (4.0f * half * half / static_cast<float>(n));
    for (std::size_t i = 0; i < n; ++i) {
        jobs::Rng rng(seed, jobs::streamKey("uniform-plane-photons"), i);
        const Vec2 u = rng.uniform2();
        const Vec3 position((2.0f * u.x - 1.0f) * half, (2.0f * u.y - 1.0f) * half, 0.0f);
        addPhoton(map, position, sampleCosineHemisphere(rng.uniform2()), power, Vec3(0, 0, 1), photonClass);
    }
    map.emitted += n;
}

inline void addEyeVertex(EyeVertices& eye, const Vec3& position, std::uint32_t pixel, const Rgb& throughput,
                         std::uint32_t bsdf = 0, const Vec3& normal = Vec3(0, 0, 1),
                         const Vec3& outgoing = glm::normalize(Vec3(0.3f, 0.1f, 1.0f))) {
    eye.vertices.append(
        EyeVertexBuffer::Record{position, normal, normal, outgoing, bsdf, Vec2(0.0f), throughput, pixel});
}

// A `photon` pass with the real pass's outputs whose maps come from `fill`.
inline PassRegistration standInPhotonPass(std::function<void(PhotonMap& caustic, PhotonMap& global)> fill) {
    class StandIn final : public Pass {
    public:
        explicit StandIn(std::function<void(PhotonMap&, PhotonMap&)> f) : fill_(std::move(f)) {}
        void run(PassContext& ctx) override {
            PhotonMap& caustic = ctx.createOutput<PhotonMap>("caustic_photons");
            PhotonMap& global = ctx.createOutput<PhotonMap>("global_photons");
            fill_(caustic, global);
        }

    private:
        std::function<void(PhotonMap&, PhotonMap&)> fill_;
    };
    PassSpec spec;
    spec.name = "photon";
    spec.doc = "test photons";
    spec.outputs = {{"caustic_photons", "PhotonMap", ""}, {"global_photons", "PhotonMap", ""}};
    return {spec, [fill] { return std::make_unique<StandIn>(fill); }};
}

}  // namespace fg::test
