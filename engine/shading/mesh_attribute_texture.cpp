#include "engine/shading/mesh_attribute_texture.h"

#include "engine/scene/shape.h"

#include <utility>

namespace fg {

namespace {

class MeshAttributeTexture final : public Texture {
public:
    MeshAttributeTexture(std::string name, float scale) : name_(std::move(name)), scale_(scale) {}

    Rgb eval(const Vec2&) const override { return Rgb(0.0f); }

    Rgb evalAt(const TexturePoint& at) const override {
        if (!at.mesh) return Rgb(0.0f);
        const MeshAttribute* attribute = at.mesh->attribute(name_);
        if (!attribute) return Rgb(0.0f);
        const std::size_t channels = static_cast<std::size_t>(attribute->channels);
        if (!attribute->perVertex()) return scale_ * value(*attribute, at.triangle * channels);
        const std::uint32_t* corners = &at.mesh->indices[3 * static_cast<std::size_t>(at.triangle)];
        const float b1 = at.barycentric.x, b2 = at.barycentric.y, b0 = 1.0f - b1 - b2;
        return scale_ * (b0 * value(*attribute, corners[0] * channels) + b1 * value(*attribute, corners[1] * channels) +
                         b2 * value(*attribute, corners[2] * channels));
    }

    // The texture belongs to no one mesh, so it has no mean of its own; mid
    // grey stands in where one is asked for (a plastic's lobe-selection
    // probability), which steers sampling only, not what is estimated.
    Rgb mean() const override { return Rgb(0.5f * scale_); }
    Vec2 scalarGradient(const Vec2&) const override { return Vec2(0.0f); }

private:
    static Rgb value(const MeshAttribute& attribute, std::size_t offset) {
        const float* v = &attribute.values[offset];
        return attribute.channels == 3 ? Rgb(v[0], v[1], v[2]) : Rgb(v[0]);
    }

    std::string name_;
    float scale_;
};

}  // namespace

std::shared_ptr<Texture> makeMeshAttributeTexture(std::string attributeName, float scale) {
    return std::make_shared<MeshAttributeTexture>(std::move(attributeName), scale);
}

}  // namespace fg
