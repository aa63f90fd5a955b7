// Loader of the native TOML scene format documented in scene_toml.h. The file
// is parsed by toml++; each table is then read through a small reader that
// records which keys the table's type understands, so that every key the
// loader did not ask for is reported as an error instead of being ignored.
// Every message carries the line of the key that caused it.
#include "engine/scene/scene_toml.h"

#include "engine/core/error.h"
#include "engine/core/text_input.h"

#include <toml++/toml.h>

#include <glm/gtc/matrix_transform.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <optional>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace fg {

namespace {

namespace fs = std::filesystem;

int lineOf(const toml::node& node) { return static_cast<int>(node.source().begin.line); }

const char* typeName(const toml::node& node) {
    switch (node.type()) {
        case toml::node_type::table: return "a table";
        case toml::node_type::array: return "an array";
        case toml::node_type::string: return "a string";
        case toml::node_type::integer: return "an integer";
        case toml::node_type::floating_point: return "a number";
        case toml::node_type::boolean: return "a boolean";
        case toml::node_type::date: return "a date";
        case toml::node_type::time: return "a time";
        case toml::node_type::date_time: return "a date-time";
        default: return "nothing";
    }
}

class Context {
public:
    Context(std::string file, std::string baseDir) : file_(std::move(file)), baseDir_(std::move(baseDir)) {}

    [[noreturn]] void fail(int line, const std::string& message) const { throw InputError(file_, line, message); }
    [[noreturn]] void fail(const toml::node& node, const std::string& message) const { fail(lineOf(node), message); }

    std::string resolve(const std::string& path) const {
        const fs::path p(path);
        if (p.is_absolute() || baseDir_.empty()) return p.lexically_normal().string();
        return (fs::path(baseDir_) / p).lexically_normal().string();
    }
    const std::string& file() const { return file_; }

    float number(const toml::node& node, const std::string& what) const {
        if (!node.is_number()) fail(node, "'" + what + "' must be a number, not " + typeName(node));
        const double value = node.is_integer() ? static_cast<double>(*node.value<std::int64_t>()) : *node.value<double>();
        if (!std::isfinite(value) || std::abs(value) > 3.0e38) fail(node, "'" + what + "' must be a finite number");
        return static_cast<float>(value);
    }
    std::string string(const toml::node& node, const std::string& what) const {
        if (!node.is_string()) fail(node, "'" + what + "' must be a string, not " + typeName(node));
        return *node.value<std::string>();
    }
    bool boolean(const toml::node& node, const std::string& what) const {
        if (!node.is_boolean()) fail(node, "'" + what + "' must be true or false, not " + typeName(node));
        return *node.value<bool>();
    }
    long long integer(const toml::node& node, const std::string& what) const {
        if (!node.is_integer()) fail(node, "'" + what + "' must be an integer, not " + typeName(node));
        return *node.value<std::int64_t>();
    }
    std::vector<float> numbers(const toml::node& node, const std::string& what, std::size_t count) const {
        const toml::array* array = node.as_array();
        if (!array || array->size() != count) {
            fail(node, "'" + what + "' must be an array of " + std::to_string(count) + " numbers");
        }
        std::vector<float> values;
        for (const toml::node& element : *array) values.push_back(number(element, what));
        return values;
    }
    Vec3 vec3(const toml::node& node, const std::string& what) const {
        const std::vector<float> v = numbers(node, what, 3);
        return {v[0], v[1], v[2]};
    }
    Vec2 vec2(const toml::node& node, const std::string& what) const {
        if (node.is_number()) return Vec2(number(node, what));
        const std::vector<float> v = numbers(node, what, 2);
        return {v[0], v[1]};
    }
    Rgb rgb(const toml::node& node, const std::string& what) const {
        if (node.is_number()) return Rgb(number(node, what));
        if (!node.is_array()) fail(node, "'" + what + "' must be [r, g, b] or a number, not " + typeName(node));
        return vec3(node, what);
    }
    const toml::table& table(const toml::node& node, const std::string& what) const {
        const toml::table* t = node.as_table();
        if (!t) fail(node, "'" + what + "' must be a table, not " + typeName(node));
        return *t;
    }

private:
    std::string file_;
    std::string baseDir_;
};

// One TOML table being read. get() both looks a key up and declares it valid
// for this table, so finish() can reject whatever was never asked for.
class Fields {
public:
    Fields(const Context& context, const toml::table& table, std::string where)
        : ctx_(context), table_(table), where_(std::move(where)) {}

    const Context& ctx() const { return ctx_; }
    const toml::table& table() const { return table_; }
    int line() const { return lineOf(table_); }

    const toml::node* get(std::string_view key) {
        allow({key});
        return table_.get(key);
    }
    const toml::node& require(std::string_view key) {
        const toml::node* node = get(key);
        if (!node) ctx_.fail(line(), "missing key '" + std::string(key) + "' in " + where_);
        return *node;
    }
    void allow(std::initializer_list<std::string_view> keys) {
        for (std::string_view k : keys) {
            if (std::find(known_.begin(), known_.end(), k) == known_.end()) known_.emplace_back(k);
        }
    }
    bool has(std::string_view key) const { return table_.get(key) != nullptr; }
    int lineOfKey(std::string_view key) const {
        const toml::node* node = table_.get(key);
        return node ? lineOf(*node) : line();
    }
    [[noreturn]] void fail(std::string_view key, const std::string& message) const { ctx_.fail(lineOfKey(key), message); }

    float number(std::string_view key, float fallback) {
        const toml::node* node = get(key);
        return node ? ctx_.number(*node, std::string(key)) : fallback;
    }
    float requireNumber(std::string_view key) { return ctx_.number(require(key), std::string(key)); }
    Vec3 vec3(std::string_view key, const Vec3& fallback) {
        const toml::node* node = get(key);
        return node ? ctx_.vec3(*node, std::string(key)) : fallback;
    }
    Vec3 requireVec3(std::string_view key) { return ctx_.vec3(require(key), std::string(key)); }
    Rgb rgb(std::string_view key, const Rgb& fallback) {
        const toml::node* node = get(key);
        return node ? ctx_.rgb(*node, std::string(key)) : fallback;
    }
    Rgb requireRgb(std::string_view key) { return ctx_.rgb(require(key), std::string(key)); }
    bool boolean(std::string_view key, bool fallback) {
        const toml::node* node = get(key);
        return node ? ctx_.boolean(*node, std::string(key)) : fallback;
    }
    std::optional<std::string> string(std::string_view key) {
        const toml::node* node = get(key);
        if (!node) return std::nullopt;
        return ctx_.string(*node, std::string(key));
    }
    std::string requireString(std::string_view key) { return ctx_.string(require(key), std::string(key)); }

    void finish() const {
        for (auto&& [key, node] : table_) {
            if (std::find(known_.begin(), known_.end(), key.str()) != known_.end()) continue;
            std::string allowed;
            for (const std::string& k : known_) allowed += (allowed.empty() ? "" : ", ") + k;
            const int keyLine = key.source().begin.line > 0 ? static_cast<int>(key.source().begin.line) : lineOf(node);
            ctx_.fail(keyLine, "unknown key '" + std::string(key.str()) + "' in " + where_ +
                                   (allowed.empty() ? std::string() : " (expected one of: " + allowed + ")"));
        }
    }

private:
    const Context& ctx_;
    const toml::table& table_;
    std::string where_;
    std::vector<std::string> known_;
};

void requireNonNegative(const Fields& f, std::string_view key, const Rgb& value) {
    if (!(value.x >= 0.0f && value.y >= 0.0f && value.z >= 0.0f)) {
        f.fail(key, "'" + std::string(key) + "' must not be negative");
    }
}

void requireUnitRange(const Fields& f, std::string_view key, const Rgb& value) {
    requireNonNegative(f, key, value);
    if (!(value.x <= 1.0f && value.y <= 1.0f && value.z <= 1.0f)) {
        f.fail(key, "'" + std::string(key) + "' must lie in [0, 1] (a larger value creates energy)");
    }
}

// Parses one TOML file into a Scene, one section after another.
class SceneBuilder {
public:
    SceneBuilder(const Context& context, Scene& scene) : ctx_(context), scene_(scene) {}

    void build(const toml::table& root) {
        Fields top(ctx_, root, "the scene file");
        top.allow({"camera", "medium", "material", "shape", "light"});
        top.finish();
        forEachTable(root, "medium", [&](Fields& f) { readMedium(f); });
        forEachTable(root, "material", [&](Fields& f) { readMaterial(f); });
        const toml::node* camera = root.get("camera");
        if (!camera) ctx_.fail(1, "missing [camera] table");
        if (!camera->is_table()) ctx_.fail(*camera, "'camera' must be a table: write [camera]");
        Fields cameraFields(ctx_, *camera->as_table(), "[camera]");
        readCamera(cameraFields);
        forEachTable(root, "shape", [&](Fields& f) { readShape(f); });
        forEachTable(root, "light", [&](Fields& f) { readLight(f); });
    }

private:
    void forEachTable(const toml::table& root, const std::string& name, const std::function<void(Fields&)>& read) {
        const toml::node* node = root.get(name);
        if (!node) return;
        const toml::array* array = node->as_array();
        if (!array) ctx_.fail(*node, "'" + name + "' must be an array of tables: write [[" + name + "]]");
        for (const toml::node& element : *array) {
            if (!element.is_table()) ctx_.fail(element, "each '" + name + "' entry must be a table: write [[" + name + "]]");
            Fields fields(ctx_, *element.as_table(), "[[" + name + "]]");
            read(fields);
            fields.finish();
        }
    }

    std::string uniqueName(Fields& f, const std::unordered_map<std::string, int>& existing, const char* kind) {
        const std::string name = f.requireString("name");
        if (name.empty()) f.fail("name", std::string(kind) + " name must not be empty");
        if (existing.count(name)) f.fail("name", std::string(kind) + " '" + name + "' is defined twice");
        return name;
    }

    int mediumReference(Fields& f, std::string_view key) {
        const std::optional<std::string> name = f.string(key);
        if (!name) return -1;
        const auto it = mediumIndex_.find(*name);
        if (it == mediumIndex_.end()) f.fail(key, "unknown medium '" + *name + "'");
        return it->second;
    }

    // ---- media ----------------------------------------------------------------

    void readMedium(Fields& f) {
        const std::string name = uniqueName(f, mediumIndex_, "medium");
        const Rgb sigmaS = f.requireRgb("sigma_s");
        requireNonNegative(f, "sigma_s", sigmaS);
        const Rgb sigmaA = f.requireRgb("sigma_a");
        requireNonNegative(f, "sigma_a", sigmaA);
        const float g = f.number("g", 0.0f);
        if (!(g > -1.0f && g < 1.0f)) f.fail("g", "'g' must lie strictly between -1 and 1");
        const float scale = f.number("scale", 1.0f);
        if (!(scale > 0.0f)) f.fail("scale", "'scale' must be positive");
        mediumIndex_[name] = static_cast<int>(scene_.media.size());
        scene_.media.emplace_back(scale * sigmaA, scale * sigmaS, g);
    }

    // ---- materials ------------------------------------------------------------

    std::shared_ptr<Texture> readTexture(Fields& f, std::string_view key, const Rgb& fallback) {
        const toml::node* node = f.get(key);
        const std::string what(key);
        if (!node) return makeConstantTexture(fallback);
        if (node->is_number() || node->is_array()) {
            const Rgb value = ctx_.rgb(*node, what);
            requireUnitRange(f, key, value);
            return makeConstantTexture(value);
        }
        if (!node->is_table()) ctx_.fail(*node, "'" + what + "' must be an RGB value or a texture table, not " + typeName(*node));
        Fields texture(ctx_, *node->as_table(), "texture '" + what + "'");
        std::shared_ptr<Texture> result;
        if (texture.has("checkerboard") && texture.has("bitmap")) {
            texture.fail("bitmap", "texture '" + what + "' takes either 'checkerboard' or 'bitmap', not both");
        }
        if (texture.has("checkerboard")) {
            Fields checker(ctx_, ctx_.table(texture.require("checkerboard"), "checkerboard"), "checkerboard");
            const Rgb even = checker.requireRgb("even");
            requireUnitRange(checker, "even", even);
            const Rgb odd = checker.requireRgb("odd");
            requireUnitRange(checker, "odd", odd);
            Vec2 scale(2.0f);
            if (const toml::node* s = checker.get("scale")) scale = ctx_.vec2(*s, "scale");
            if (!(scale.x > 0.0f && scale.y > 0.0f)) checker.fail("scale", "'scale' must be positive");
            checker.finish();
            result = makeCheckerboardTexture(even, odd, scale);
        } else if (texture.has("bitmap")) {
            const std::string file = ctx_.resolve(texture.requireString("bitmap"));
            Vec2 uvScale(1.0f);
            if (const toml::node* s = texture.get("uv_scale")) uvScale = ctx_.vec2(*s, "uv_scale");
            if (!(uvScale.x != 0.0f && uvScale.y != 0.0f)) texture.fail("uv_scale", "'uv_scale' must not be zero");
            requireFile(texture, "bitmap", file);
            try {
                result = loadBitmapTexture(file, uvScale);
            } catch (const InputError& e) {
                texture.fail("bitmap", e.what());
            }
        } else {
            ctx_.fail(*node, "texture '" + what + "' needs either 'checkerboard' or 'bitmap'");
        }
        texture.finish();
        return result;
    }

    void requireFile(const Fields& f, std::string_view key, const std::string& resolved) {
        std::error_code ec;
        if (!fs::is_regular_file(resolved, ec)) f.fail(key, "file not found: " + resolved);
    }

    float readIor(Fields& f, std::string_view key, float fallback) {
        const toml::node* node = f.get(key);
        if (!node) return fallback;
        if (node->is_string()) {
            const std::string name = *node->value<std::string>();
            const std::optional<float> preset = dielectricIorPreset(name);
            if (!preset) ctx_.fail(*node, "unknown IOR preset '" + name + "'");
            return *preset;
        }
        const float ior = ctx_.number(*node, std::string(key));
        if (!(ior > 0.0f)) ctx_.fail(*node, "'" + std::string(key) + "' must be positive");
        return ior;
    }

    float relativeIor(Fields& f) {
        const float interior = readIor(f, "ior", 1.5f);
        const float exterior = readIor(f, "exterior_ior", 1.0f);
        return interior / exterior;
    }

    float readAlpha(Fields& f) {
        const float alpha = f.number("alpha", 0.1f);
        if (!(alpha > 0.0f)) f.fail("alpha", "'alpha' must be positive");
        return alpha;
    }

    // GGX by default, which is what every rough material meant before the key existed.
    MicrofacetType readDistribution(Fields& f) {
        const std::string name = f.string("distribution").value_or("ggx");
        const std::optional<MicrofacetType> type = microfacetTypeFromName(name);
        if (!type) f.fail("distribution", "unknown distribution '" + name + "' (expected ggx or beckmann)");
        return *type;
    }

    ConductorIor readConductorIor(Fields& f) {
        const bool hasPreset = f.has("material");
        const bool hasEta = f.has("eta"), hasK = f.has("k");
        if (hasPreset && (hasEta || hasK)) f.fail("material", "give either 'material' or 'eta' and 'k', not both");
        if (hasEta != hasK) f.fail(hasEta ? "eta" : "k", "'eta' and 'k' must be given together");
        if (hasEta) {
            const Rgb eta = f.requireRgb("eta");
            requireNonNegative(f, "eta", eta);
            const Rgb k = f.requireRgb("k");
            requireNonNegative(f, "k", k);
            f.allow({"material"});
            return {eta, k};
        }
        f.allow({"eta", "k"});
        const std::string name = f.string("material").value_or("none");
        // An imaginary index (eta = 0, k = 1) reflects everything at every angle.
        if (name == "none") return {Rgb(0.0f), Rgb(1.0f)};
        const std::optional<ConductorIor> preset = conductorPreset(name);
        if (!preset) f.fail("material", "unknown conductor '" + name + "'");
        return *preset;
    }

    Rgb readSpecular(Fields& f, std::string_view key) {
        const Rgb value = f.rgb(key, Rgb(1.0f));
        requireUnitRange(f, key, value);
        return value;
    }

    void readMaterial(Fields& f) {
        const std::string name = uniqueName(f, materialIndex_, "material");
        const std::string type = f.requireString("type");
        std::shared_ptr<Bsdf> bsdf;
        if (type == "diffuse") {
            bsdf = makeDiffuse(readTexture(f, "reflectance", Rgb(0.5f)));
        } else if (type == "dielectric") {
            const float eta = relativeIor(f);
            const Rgb reflectance = readSpecular(f, "specular_reflectance");
            const Rgb transmittance = readSpecular(f, "specular_transmittance");
            bsdf = makeDielectric(eta, reflectance, transmittance);
        } else if (type == "thindielectric") {
            bsdf = makeThinDielectric(relativeIor(f));
        } else if (type == "conductor") {
            const ConductorIor ior = readConductorIor(f);
            bsdf = makeConductor(ior, readSpecular(f, "specular_reflectance"));
        } else if (type == "roughconductor") {
            const ConductorIor ior = readConductorIor(f);
            const float alpha = readAlpha(f);
            const Rgb specular = readSpecular(f, "specular_reflectance");
            bsdf = makeRoughConductor(ior, alpha, specular, readDistribution(f));
        } else if (type == "roughdielectric") {
            const float eta = relativeIor(f);
            const float alpha = readAlpha(f);
            bsdf = makeRoughDielectric(eta, alpha, readDistribution(f));
        } else if (type == "plastic") {
            auto reflectance = readTexture(f, "reflectance", Rgb(0.5f));
            const float eta = relativeIor(f);
            bsdf = makePlastic(std::move(reflectance), eta, f.boolean("nonlinear", false));
        } else if (type == "roughplastic") {
            auto reflectance = readTexture(f, "reflectance", Rgb(0.5f));
            const float eta = relativeIor(f);
            const float alpha = readAlpha(f);
            const MicrofacetType distribution = readDistribution(f);
            const Rgb specular = readSpecular(f, "specular_reflectance");
            bsdf = makeRoughPlastic(std::move(reflectance), eta, alpha, distribution, f.boolean("nonlinear", false),
                                    specular);
        } else if (type == "null") {
            bsdf = makeNull();
        } else if (type == "twosided") {
            const std::string inner = f.requireString("inner");
            const auto it = materialIndex_.find(inner);
            if (it == materialIndex_.end()) f.fail("inner", "unknown material '" + inner + "' (define it above this one)");
            bsdf = makeTwoSided(scene_.bsdfs[static_cast<std::size_t>(it->second)]);
        } else {
            f.fail("type", "unknown material type '" + type +
                               "' (expected diffuse, dielectric, thindielectric, conductor, roughconductor, "
                               "roughdielectric, plastic, roughplastic, null or twosided)");
        }
        materialIndex_[name] = static_cast<int>(scene_.bsdfs.size());
        scene_.bsdfs.push_back(std::move(bsdf));
    }

    // ---- camera ---------------------------------------------------------------

    void readCamera(Fields& f) {
        Camera& camera = scene_.camera;
        camera.eye = f.requireVec3("eye");
        camera.target = f.requireVec3("target");
        if (glm::length(camera.target - camera.eye) <= 0.0f) f.fail("target", "camera 'target' equals 'eye'");
        camera.up = f.vec3("up", Vec3(0.0f, 1.0f, 0.0f));
        const Vec3 forward = glm::normalize(camera.target - camera.eye);
        if (!(glm::length(camera.up) > 0.0f) ||
            glm::length(glm::cross(forward, glm::normalize(camera.up))) < 1e-4f) {
            f.fail(f.has("up") ? "up" : "target", "camera 'up' must not be parallel to the viewing direction");
        }
        const std::string projection = f.string("type").value_or("perspective");
        if (projection == "orthographic") {
            if (f.has("fov")) f.fail("fov", "an orthographic camera takes 'view_height', not 'fov'");
            camera.orthographic = true;
            camera.orthoHalfHeight = 0.5f * f.number("view_height", 2.0f);
            if (!(camera.orthoHalfHeight > 0.0f) || !std::isfinite(camera.orthoHalfHeight)) {
                f.fail("view_height", "'view_height' must be positive");
            }
        } else if (projection == "perspective") {
            if (f.has("view_height")) f.fail("view_height", "'view_height' applies to orthographic cameras only");
            camera.fovYDegrees = f.number("fov", 40.0f);
            if (!(camera.fovYDegrees > 0.0f && camera.fovYDegrees < 180.0f)) f.fail("fov", "'fov' must lie in (0, 180) degrees");
        } else {
            f.fail("type", "unknown camera type '" + projection + "' (expected perspective or orthographic)");
        }
        for (const char* key : {"width", "height"}) {
            const toml::node* node = f.get(key);
            if (!node) continue;
            const long long value = ctx_.integer(*node, key);
            if (value < 1 || value > 65536) ctx_.fail(*node, std::string("'") + key + "' must lie in [1, 65536]");
            (std::string_view(key) == "width" ? camera.width : camera.height) = static_cast<int>(value);
        }
        camera.medium = mediumReference(f, "medium");
        f.finish();
    }

    // ---- transforms -----------------------------------------------------------

    Mat4 readTransformOp(const toml::node& node) {
        const toml::table* table = node.as_table();
        if (!table || table->size() != 1) {
            ctx_.fail(node, "each transform step must be a table with one key: translate, scale, rotate, matrix or lookat");
        }
        std::string op;
        const toml::node* valueNode = nullptr;
        for (auto&& [key, entry] : *table) {
            op = std::string(key.str());
            valueNode = &entry;
        }
        const toml::node& value = *valueNode;
        if (op == "translate") return glm::translate(Mat4(1.0f), ctx_.vec3(value, op));
        if (op == "scale") {
            const Vec3 s = value.is_number() ? Vec3(ctx_.number(value, op)) : ctx_.vec3(value, op);
            if (s.x == 0.0f || s.y == 0.0f || s.z == 0.0f) ctx_.fail(value, "'scale' must not be zero");
            return glm::scale(Mat4(1.0f), s);
        }
        if (op == "rotate") {
            Fields f(ctx_, ctx_.table(value, op), "rotate");
            const Vec3 axis = f.requireVec3("axis");
            if (!(glm::length(axis) > 0.0f)) f.fail("axis", "rotation 'axis' must not be zero");
            const float angle = f.requireNumber("angle");
            f.finish();
            return glm::rotate(Mat4(1.0f), glm::radians(angle), glm::normalize(axis));
        }
        if (op == "matrix") return readMatrix(value);
        if (op == "lookat") {
            Fields f(ctx_, ctx_.table(value, op), "lookat");
            const Vec3 origin = f.requireVec3("origin");
            const Vec3 target = f.requireVec3("target");
            const Vec3 up = f.vec3("up", Vec3(0.0f, 1.0f, 0.0f));
            f.finish();
            if (!(glm::length(target - origin) > 0.0f)) f.fail("target", "lookat 'target' equals 'origin'");
            const Vec3 dir = glm::normalize(target - origin);
            const Vec3 left = glm::cross(up, dir);
            if (!(glm::length(left) > 1e-6f)) f.fail("up", "lookat 'up' is parallel to the viewing direction");
            const Vec3 x = glm::normalize(left);
            const Vec3 y = glm::cross(dir, x);
            Mat4 m(1.0f);
            m[0] = Vec4(x, 0.0f);
            m[1] = Vec4(y, 0.0f);
            m[2] = Vec4(dir, 0.0f);
            m[3] = Vec4(origin, 1.0f);
            return m;
        }
        ctx_.fail(node, "unknown transform step '" + op + "' (expected translate, scale, rotate, matrix or lookat)");
    }

    Mat4 readMatrix(const toml::node& node) {
        std::vector<float> rowMajor;
        const toml::array* array = node.as_array();
        if (array && array->size() == 4 && array->get(0)->is_array()) {
            for (const toml::node& row : *array) {
                const std::vector<float> r = ctx_.numbers(row, "matrix", 4);
                rowMajor.insert(rowMajor.end(), r.begin(), r.end());
            }
        } else {
            rowMajor = ctx_.numbers(node, "matrix", 16);
        }
        Mat4 m;
        for (int row = 0; row < 4; ++row) {
            for (int col = 0; col < 4; ++col) m[col][row] = rowMajor[static_cast<std::size_t>(4 * row + col)];
        }
        if (m[0][3] != 0.0f || m[1][3] != 0.0f || m[2][3] != 0.0f || m[3][3] != 1.0f) {
            ctx_.fail(node, "'matrix' must be affine: its last row must be [0, 0, 0, 1]");
        }
        return m;
    }

    Mat4 readTransform(const toml::node& node) {
        const toml::array* steps = node.as_array();
        if (!steps) ctx_.fail(node, "'transform' must be an array of steps, e.g. [{ translate = [0, 1, 0] }]");
        Mat4 m(1.0f);
        for (const toml::node& step : *steps) m = readTransformOp(step) * m;
        const float det = glm::determinant(Mat3(m));
        if (!(std::abs(det) > 1e-12f) || !std::isfinite(det)) ctx_.fail(node, "'transform' is singular");
        return m;
    }

    // ---- shapes ---------------------------------------------------------------

    void readShape(Fields& f) {
        const std::size_t index = scene_.shapes.size();
        Shape shape;
        const std::string type = f.requireString("type");
        const bool flip = f.boolean("flip_normals", false);
        if (type == "sphere") {
            if (f.has("transform")) f.fail("transform", "spheres take 'center' and 'radius'; 'transform' is not supported");
            Sphere sphere;
            sphere.center = f.vec3("center", Vec3(0.0f));
            sphere.radius = f.number("radius", 1.0f);
            if (!(sphere.radius > 0.0f)) f.fail("radius", "sphere 'radius' must be positive");
            shape.geometry = sphere;
            shape.flipNormals = flip;
        } else {
            TriangleMesh mesh;
            if (type == "obj") {
                const std::string file = ctx_.resolve(f.requireString("file"));
                requireFile(f, "file", file);
                try {
                    mesh = loadObjMesh(file);
                } catch (const InputError& e) {
                    f.fail("file", e.what());
                }
                shape.name = fs::path(file).stem().string();
            } else if (type == "rectangle") {
                mesh = makeRectangleMesh();
            } else if (type == "disk") {
                int segments = 128;
                if (const toml::node* node = f.get("segments")) {
                    const long long value = ctx_.integer(*node, "segments");
                    if (value < 3 || value > 1000000) ctx_.fail(*node, "'segments' must lie in [3, 1000000]");
                    segments = static_cast<int>(value);
                }
                mesh = makeDiskMesh(segments);
            } else if (type == "cube") {
                mesh = makeCubeMesh();
            } else if (type == "cylinder") {
                const Vec3 p0 = f.vec3("p0", Vec3(0.0f));
                const Vec3 p1 = f.vec3("p1", Vec3(0.0f, 0.0f, 1.0f));
                const float radius = f.number("radius", 1.0f);
                if (!(radius > 0.0f) || !std::isfinite(radius)) f.fail("radius", "cylinder 'radius' must be positive");
                if (!(glm::length(p1 - p0) > 0.0f)) f.fail(f.has("p1") ? "p1" : "p0", "cylinder 'p0' and 'p1' must differ");
                mesh = makeCylinderMesh();
                mesh.transform(cylinderPlacement(p0, p1, radius));
            } else {
                f.fail("type", "unknown shape type '" + type + "' (expected obj, rectangle, disk, cube, cylinder or sphere)");
            }
            if (const toml::node* transform = f.get("transform")) mesh.transform(readTransform(*transform));
            if (flip) mesh.flipNormals();
            shape.geometry = std::move(mesh);
        }
        if (std::optional<std::string> name = f.string("name")) shape.name = *name;
        if (shape.name.empty()) shape.name = type + std::to_string(index);

        const std::string material = f.requireString("material");
        const auto it = materialIndex_.find(material);
        if (it == materialIndex_.end()) f.fail("material", "unknown material '" + material + "'");
        shape.bsdf = it->second;
        shape.interiorMedium = mediumReference(f, "interior");
        shape.exteriorMedium = mediumReference(f, "exterior");

        const Rgb emission = f.rgb("emission", Rgb(0.0f));
        requireNonNegative(f, "emission", emission);
        const bool twoSided = f.boolean("two_sided_emission", false);
        if (f.has("two_sided_emission") && !f.has("emission")) {
            f.fail("two_sided_emission", "'two_sided_emission' needs 'emission'");
        }
        if (!isBlack(emission)) {
            shape.areaLight = static_cast<int>(scene_.lights.size());
            scene_.lights.push_back(makeAreaLight(shape, emission, twoSided));
            scene_.lightShape.push_back(static_cast<int>(index));
        }
        scene_.shapes.push_back(std::move(shape));
    }

    // ---- lights ---------------------------------------------------------------

    Rgb nonNegativeRgb(Fields& f, std::string_view key) {
        const Rgb value = f.requireRgb(key);
        requireNonNegative(f, key, value);
        return value;
    }

    Vec3 nonZeroDirection(Fields& f, std::string_view key) {
        const Vec3 d = f.requireVec3(key);
        if (!(glm::length(d) > 0.0f)) f.fail(key, "'" + std::string(key) + "' must not be zero");
        return glm::normalize(d);
    }

    void readLight(Fields& f) {
        const std::string type = f.requireString("type");
        std::shared_ptr<Light> light;
        if (type == "point") {
            const Vec3 position = f.requireVec3("position");
            light = makePointLight(position, nonNegativeRgb(f, "intensity"));
        } else if (type == "spot") {
            const Vec3 position = f.requireVec3("position");
            Vec3 direction;
            if (f.has("target") == f.has("direction")) {
                ctx_.fail(f.line(), "a spot light needs exactly one of 'target' and 'direction'");
            }
            if (f.has("target")) {
                const Vec3 target = f.requireVec3("target");
                if (!(glm::length(target - position) > 0.0f)) f.fail("target", "spot 'target' equals 'position'");
                direction = glm::normalize(target - position);
                f.allow({"direction"});
            } else {
                direction = nonZeroDirection(f, "direction");
                f.allow({"target"});
            }
            const Rgb intensity = nonNegativeRgb(f, "intensity");
            const float cutoff = f.number("cutoff_angle", 20.0f);
            if (!(cutoff > 0.0f && cutoff < 180.0f)) f.fail("cutoff_angle", "'cutoff_angle' must lie in (0, 180) degrees");
            const float beam = f.number("beam_width", 0.75f * cutoff);
            if (!(beam > 0.0f && beam <= cutoff)) f.fail("beam_width", "'beam_width' must lie in (0, cutoff_angle]");
            light = makeSpotLight(position, direction, intensity, cutoff, beam);
        } else if (type == "directional") {
            const Vec3 direction = nonZeroDirection(f, "direction");
            light = makeDirectionalLight(direction, nonNegativeRgb(f, "irradiance"));
        } else if (type == "constant") {
            light = makeConstantEnvironment(nonNegativeRgb(f, "radiance"));
        } else if (type == "envmap") {
            const std::string file = ctx_.resolve(f.requireString("file"));
            requireFile(f, "file", file);
            const float scale = f.number("scale", 1.0f);
            if (!(scale > 0.0f)) f.fail("scale", "'scale' must be positive");
            Mat3 toWorld(1.0f);
            if (const toml::node* transform = f.get("transform")) {
                const Mat4 m = readTransform(*transform);
                toWorld = Mat3(m);
                const Mat3 shouldBeIdentity = glm::transpose(toWorld) * toWorld;
                float error = std::abs(glm::determinant(toWorld) - 1.0f) + glm::length(Vec3(m[3]));
                for (int c = 0; c < 3; ++c) error += glm::length(shouldBeIdentity[c] - Mat3(1.0f)[c]);
                if (error > 1e-3f) ctx_.fail(*transform, "an environment map's 'transform' may only rotate");
            }
            RgbImage image;
            try {
                image = readRgbImage(file);
            } catch (const InputError& e) {
                f.fail("file", e.what());
            }
            light = makeEnvironmentMap(image, scale, toWorld);
        } else {
            f.fail("type", "unknown light type '" + type + "' (expected point, spot, directional, constant or envmap)");
        }
        scene_.lights.push_back(std::move(light));
        scene_.lightShape.push_back(-1);
    }

    const Context& ctx_;
    Scene& scene_;
    std::unordered_map<std::string, int> mediumIndex_;
    std::unordered_map<std::string, int> materialIndex_;
};

}  // namespace

Scene parseTomlScene(std::string_view text, const std::string& pathForMessages, const std::string& baseDir) {
    toml::table root;
    try {
        root = toml::parse(text, pathForMessages);
    } catch (const toml::parse_error& e) {
        throw InputError(pathForMessages, static_cast<int>(e.source().begin.line), std::string(e.description()));
    }
    const Context context(pathForMessages, baseDir);
    Scene scene;
    scene.sourcePath = pathForMessages;
    SceneBuilder(context, scene).build(root);
    scene.finalize();
    return scene;
}

Scene loadTomlScene(const std::string& path) {
    const std::string text = readTextInput(path, "scene file");
    const std::string baseDir = fs::path(path).parent_path().string();
    return parseTomlScene(text, path, baseDir.empty() ? "." : baseDir);
}

}  // namespace fg
