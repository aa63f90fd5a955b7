// Mitsuba XML scene import (formats of Mitsuba 0.5/0.6 and Mitsuba 3, see
// scene_xml.h for what is read and how it maps onto fg::Scene).
//
// Loading runs in two stages. The preprocessor walks the pugixml trees of the
// scene file and its includes and produces one tree of plain nodes: includes
// spliced in, <default>/<path> consumed, $parameters substituted, 0.x
// parameter names rewritten to Mitsuba 3's, and every node tagged with its file
// and line (pugixml reports byte offsets; each file keeps its line starts to
// turn them into line numbers). The builder then reads that tree: every plugin
// element is read through a Props object that records which of its children
// were asked for, so that a child nobody asked for is reported as an unknown
// parameter instead of being ignored. Objects with an id are built on first
// use and shared afterwards (bsdfs, textures, media); unreferenced ones are
// still built, so their errors are reported too.
//
// Spectra become RGB through engine/scene/spectrum.h (CIE 1931 observer). Angle-
// weighted vertex normals for meshes without normals follow Thuermer and
// Wuethrich 1998, "Computing vertex normals from polygonal facets", as
// Mitsuba computes them.
#include "engine/scene/scene_xml.h"

#include "engine/shading/bsdf_adapters.h"
#include "engine/shading/mesh_attribute_texture.h"
#include "engine/shading/principled.h"

#include "engine/core/error.h"
#include "engine/core/text_input.h"
#include "engine/scene/spectrum.h"

#include <pugixml.hpp>

#include <glm/gtc/matrix_transform.hpp>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <numbers>
#include <optional>
#include <set>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace fg {

namespace {

namespace fs = std::filesystem;

// ---- source files and the preprocessed tree -----------------------------------

struct Version {
    int major = 3, minor = 0, patch = 0;
    bool legacy() const { return major < 2; }  // Mitsuba 0.x naming and defaults
};

struct SourceFile {
    std::string path;       // as it appears in messages
    std::string directory;  // for relative file names
    std::string text;
    std::vector<std::size_t> lineStarts;
    pugi::xml_document document;

    int lineAt(std::ptrdiff_t offset) const {
        if (offset < 0) return 0;
        const auto it = std::upper_bound(lineStarts.begin(), lineStarts.end(), static_cast<std::size_t>(offset));
        return static_cast<int>(it - lineStarts.begin());
    }
};

struct Node {
    std::string tag;
    std::vector<std::pair<std::string, std::string>> attributes;
    std::vector<Node> children;
    const SourceFile* file = nullptr;
    int line = 0;
    Version version;

    const std::string* attribute(std::string_view name) const {
        for (const auto& [key, value] : attributes)
            if (key == name) return &value;
        return nullptr;
    }
};

[[noreturn]] void fail(const Node& node, const std::string& message) {
    throw InputError(node.file->path, node.line, message);
}

std::string inQuotes(std::string_view s) {
    std::string out;
    out.reserve(s.size() + 2);
    out += '\'';
    out += s;
    out += '\'';
    return out;
}

std::string joinNames(const std::vector<std::string>& names) {
    std::string list;
    for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
    return list;
}

// Prefix naming the plugin an element belongs to, for messages ("bsdf 'diffuse': ").
std::string prefix(const std::string& context) { return context.empty() ? context : context + ": "; }

// Attributes an element may carry; anything else is a typo worth reporting.
void checkAttributes(const Node& node, std::initializer_list<std::string_view> allowed, const std::string& context = "") {
    for (const auto& [key, value] : node.attributes) {
        if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
        std::string list;
        for (std::string_view a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
        fail(node, prefix(context) + "unknown attribute " + inQuotes(key) + " of <" + node.tag + ">" +
                       (list.empty() ? std::string(" (it takes none)") : " (expected: " + list + ")"));
    }
}

const std::string& requireAttribute(const Node& node, std::string_view name, const std::string& context = "") {
    const std::string* value = node.attribute(name);
    if (!value) fail(node, prefix(context) + "<" + node.tag + "> needs the attribute " + inQuotes(name));
    return *value;
}

// ---- value syntax -----------------------------------------------------------

std::string_view trim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
    return s;
}

std::optional<double> parseNumber(std::string_view text) {
    text = trim(text);
    if (!text.empty() && text.front() == '+') text.remove_prefix(1);
    double value = 0.0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (ec != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
    if (!std::isfinite(value) || std::abs(value) > 3.0e38) return std::nullopt;
    return value;
}

std::optional<long long> parseInteger(std::string_view text) {
    text = trim(text);
    if (!text.empty() && text.front() == '+') text.remove_prefix(1);
    long long value = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (ec != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
    return value;
}

// "1, 2, 3" or "1 2 3": numbers separated by commas and/or white space.
std::optional<std::vector<float>> parseNumberList(std::string_view text) {
    std::vector<float> values;
    std::size_t i = 0;
    bool expectValue = true;
    while (i < text.size()) {
        const char c = text[i];
        if (std::isspace(static_cast<unsigned char>(c))) {
            ++i;
        } else if (c == ',') {
            if (expectValue) return std::nullopt;  // ", ," or a leading comma
            expectValue = true;
            ++i;
        } else {
            std::size_t j = i;
            while (j < text.size() && text[j] != ',' && !std::isspace(static_cast<unsigned char>(text[j]))) ++j;
            const std::optional<double> v = parseNumber(text.substr(i, j - i));
            if (!v) return std::nullopt;
            values.push_back(static_cast<float>(*v));
            expectValue = false;
            i = j;
        }
    }
    if (values.empty() || (expectValue && !values.empty())) return std::nullopt;
    return values;
}

bool isIdentifierStart(char c) { return std::isalpha(static_cast<unsigned char>(c)) || c == '_'; }
bool isIdentifierChar(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; }
bool isIdentifier(std::string_view s) {
    return !s.empty() && isIdentifierStart(s.front()) && std::all_of(s.begin(), s.end(), isIdentifierChar);
}

// Mitsuba 0.x camelCase parameter names -> Mitsuba 3 snake_case ("intIOR" -> "int_ior").
std::string toSnakeCase(std::string_view name) {
    std::string out;
    for (std::size_t i = 0; i < name.size(); ++i) {
        const char c = name[i];
        if (std::isupper(static_cast<unsigned char>(c))) {
            const bool afterLower = i > 0 && (std::islower(static_cast<unsigned char>(name[i - 1])) ||
                                              std::isdigit(static_cast<unsigned char>(name[i - 1])));
            const bool acronymEnd = i > 0 && i + 1 < name.size() && std::isupper(static_cast<unsigned char>(name[i - 1])) &&
                                    std::islower(static_cast<unsigned char>(name[i + 1]));
            if (afterLower || acronymEnd) out += '_';
            out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        } else {
            out += c;
        }
    }
    return out;
}

float srgbToLinear(float v) { return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f); }

// ---- file lookup ------------------------------------------------------------

struct FileResolver {
    std::string sceneDirectory;
    std::vector<std::string> searchPaths;  // from <path>, in document order

    // First existing candidate; if none exists, the name relative to `currentDirectory`
    // (so that the caller's "not found" message shows a sensible path).
    std::string resolve(const std::string& name, const std::string& currentDirectory) const {
        const fs::path p(name);
        if (p.is_absolute()) return p.lexically_normal().string();
        std::vector<fs::path> candidates;
        for (auto it = searchPaths.rbegin(); it != searchPaths.rend(); ++it) candidates.push_back(fs::path(*it) / p);
        candidates.push_back(fs::path(currentDirectory) / p);
        candidates.push_back(fs::path(sceneDirectory) / p);
        std::error_code ec;
        for (const fs::path& c : candidates) {
            if (fs::exists(c, ec)) return c.lexically_normal().string();
        }
        return (fs::path(currentDirectory) / p).lexically_normal().string();
    }
};

// ---- preprocessing: includes, defaults, substitution, 0.x names --------------

class Preprocessor {
public:
    Preprocessor(const std::map<std::string, std::string>& defines, FileResolver& resolver) : resolver_(resolver) {
        for (const auto& [name, value] : defines) {
            if (!isIdentifier(name)) {
                throw InputError("scene parameter " + inQuotes(name) + " (--define or scene_defines): not a valid name");
            }
            parameters_[name] = {value, true, false, false};
        }
    }

    // The source files must outlive the node tree that points into them.
    std::vector<std::unique_ptr<SourceFile>> takeFiles() { return std::move(files_); }

    Node load(const std::string& path) {
        const SourceFile& file = readFile(path, nullptr);
        Node root = rootNode(file);
        includeStack_.push_back(canonical(path));
        expand(file.document.document_element(), root, file, root.version, 0);
        includeStack_.pop_back();
        for (const auto& [name, p] : parameters_) {
            if (p.fromDefine && !p.declared && !p.used) {
                throw InputError(path, 0, "scene parameter " + inQuotes(name) +
                                              " is given (--define or scene_defines) but the scene neither declares "
                                              "it with <default> nor uses $" + name);
            }
        }
        return root;
    }

private:
    struct Parameter {
        std::string value;
        bool fromDefine = false;
        bool declared = false;  // by a <default>
        bool used = false;
    };

    static std::string canonical(const std::string& path) {
        std::error_code ec;
        const fs::path c = fs::weakly_canonical(path, ec);
        return ec ? fs::path(path).lexically_normal().string() : c.string();
    }

    const SourceFile& readFile(const std::string& path, const Node* includedFrom) {
        auto file = std::make_unique<SourceFile>();
        file->path = path;
        const std::string dir = fs::path(path).parent_path().string();
        file->directory = dir.empty() ? "." : dir;
        try {
            file->text = readTextInput(path, includedFrom ? "included file" : "scene file");
        } catch (const InputError& e) {
            if (includedFrom) fail(*includedFrom, e.what());
            throw;
        }
        file->lineStarts.push_back(0);
        for (std::size_t i = 0; i < file->text.size(); ++i)
            if (file->text[i] == '\n') file->lineStarts.push_back(i + 1);
        const pugi::xml_parse_result result =
            file->document.load_buffer(file->text.data(), file->text.size(), pugi::parse_default, pugi::encoding_utf8);
        if (!result) throw InputError(path, file->lineAt(result.offset), std::string("XML syntax: ") + result.description());
        files_.push_back(std::move(file));
        return *files_.back();
    }

    Node rootNode(const SourceFile& file, const Version* inherited = nullptr) {
        const pugi::xml_node element = file.document.document_element();
        Node root;
        root.tag = element.name();
        root.file = &file;
        root.line = file.lineAt(element.offset_debug());
        if (root.tag != "scene") fail(root, "the root element must be <scene>, not <" + root.tag + ">");
        for (const pugi::xml_attribute a : element.attributes()) root.attributes.emplace_back(a.name(), a.value());
        checkAttributes(root, {"version"});
        const std::string* version = root.attribute("version");
        if (version) {
            root.version = parseVersion(root, *version);
        } else if (inherited) {
            root.version = *inherited;
        } else {
            fail(root, "<scene> needs a version attribute (e.g. version=\"3.0.0\")");
        }
        return root;
    }

    static Version parseVersion(const Node& node, const std::string& text) {
        Version v;
        int* parts[3] = {&v.major, &v.minor, &v.patch};
        std::stringstream stream(text);
        std::string part;
        int count = 0;
        bool ok = true;
        while (std::getline(stream, part, '.')) {
            const std::optional<long long> n = parseInteger(part);
            if (count >= 3 || !n || *n < 0 || *n > 1000) {
                ok = false;
                break;
            }
            *parts[count++] = static_cast<int>(*n);
        }
        ok = ok && count >= 1;
        const bool supported = ok && ((v.major == 0 && (v.minor == 5 || v.minor == 6)) || v.major == 2 || v.major == 3);
        if (!supported) fail(node, "unsupported scene version " + inQuotes(text) + " (supported: 0.5.x, 0.6.x, 2.x.x, 3.x.x)");
        return v;
    }

    std::string substitute(const std::string& value, const Node& at) {
        std::string out;
        for (std::size_t i = 0; i < value.size(); ++i) {
            if (value[i] != '$' || i + 1 >= value.size() || !isIdentifierStart(value[i + 1])) {
                out += value[i];
                continue;
            }
            std::size_t j = i + 1;
            while (j < value.size() && isIdentifierChar(value[j])) ++j;
            const std::string name = value.substr(i + 1, j - i - 1);
            const auto it = parameters_.find(name);
            if (it == parameters_.end()) {
                fail(at, "undefined parameter $" + name + " (declare it with <default name=\"" + name +
                             "\" value=\"...\"/> or give it with --define " + name + "=...)");
            }
            it->second.used = true;
            out += it->second.value;
            i = j - 1;
        }
        return out;
    }

    // The preprocessor and the builder recurse once per element level, so the
    // depth is bounded before a deep document can exhaust the stack; real
    // scenes nest a handful of levels.
    static constexpr int kMaxElementDepth = 256;
    static constexpr std::size_t kMaxIncludeDepth = 32;

    // `depth` is the nesting depth of `parent` below <scene>, counted through includes.
    void expand(const pugi::xml_node& element, Node& parent, const SourceFile& file, const Version& version, int depth) {
        for (const pugi::xml_node child : element.children()) {
            if (child.type() == pugi::node_pcdata || child.type() == pugi::node_cdata) {
                if (!trim(child.value()).empty()) {
                    Node at;
                    at.file = &file;
                    at.line = file.lineAt(child.offset_debug());
                    fail(at, "unexpected text inside <" + std::string(element.name()) + ">");
                }
                continue;
            }
            if (child.type() != pugi::node_element) continue;  // comments, declarations

            Node node;
            node.tag = child.name();
            node.file = &file;
            node.line = file.lineAt(child.offset_debug());
            node.version = version;
            if (depth + 1 > kMaxElementDepth)
                fail(node, "elements nested more than " + std::to_string(kMaxElementDepth) + " deep");
            for (const pugi::xml_attribute a : child.attributes()) {
                if (node.attribute(a.name())) fail(node, "attribute " + inQuotes(a.name()) + " given twice");
                node.attributes.emplace_back(a.name(), substitute(a.value(), node));
            }
            if (version.legacy()) {
                if (node.tag == "lookAt") node.tag = "lookat";
                if (node.tag != "default") {
                    for (auto& [key, value] : node.attributes)
                        if (key == "name") value = toSnakeCase(value);
                }
            }

            if (node.tag == "default") {
                checkAttributes(node, {"name", "value"});
                const std::string& name = requireAttribute(node, "name");
                const std::string& value = requireAttribute(node, "value");
                if (!isIdentifier(name)) fail(node, "<default> name " + inQuotes(name) + " is not a valid parameter name");
                if (parent.tag != "scene") fail(node, "<default> must be a child of <scene>");
                Parameter& p = parameters_[name];
                if (!p.fromDefine && !p.declared) p.value = value;
                p.declared = true;
                continue;
            }
            if (node.tag == "path") {
                checkAttributes(node, {"value"});
                const fs::path dir(requireAttribute(node, "value"));
                resolver_.searchPaths.push_back(
                    (dir.is_absolute() ? dir : fs::path(file.directory) / dir).lexically_normal().string());
                continue;
            }
            if (node.tag == "include") {
                checkAttributes(node, {"filename"});
                include(node, parent, file, depth);
                continue;
            }
            expand(child, node, file, version, depth + 1);
            parent.children.push_back(std::move(node));
        }
    }

    void include(const Node& node, Node& parent, const SourceFile& file, int depth) {
        const std::string& name = requireAttribute(node, "filename");
        const std::string path = resolver_.resolve(name, file.directory);
        std::error_code ec;
        if (!fs::is_regular_file(path, ec)) fail(node, "included file not found: " + path);
        const std::string key = canonical(path);
        if (std::find(includeStack_.begin(), includeStack_.end(), key) != includeStack_.end()) {
            fail(node, "include cycle: " + path + " includes itself (directly or through other files)");
        }
        if (includeStack_.size() > kMaxIncludeDepth)
            fail(node, "includes nested more than " + std::to_string(kMaxIncludeDepth) + " deep");
        const SourceFile& included = readFile(path, &node);
        const Node includedRoot = rootNode(included, &node.version);
        includeStack_.push_back(key);
        expand(included.document.document_element(), parent, included, includedRoot.version, depth);
        includeStack_.pop_back();
    }

    FileResolver& resolver_;
    std::map<std::string, Parameter> parameters_;
    std::vector<std::unique_ptr<SourceFile>> files_;
    std::vector<std::string> includeStack_;
};

// ---- reading one plugin element ----------------------------------------------

const std::set<std::string, std::less<>> kValueTags = {"float", "integer", "boolean", "string", "point", "vector",
                                                       "rgb", "srgb", "spectrum", "transform"};
const std::set<std::string, std::less<>> kObjectTags = {"bsdf", "texture", "medium", "phase", "emitter", "shape",
                                                        "sensor", "film", "rfilter", "sampler", "integrator"};

// A child of a plugin element: a named value, or a nested / referenced object.
struct Entry {
    const Node* node = nullptr;  // the value element, or the object element (the target of a <ref>)
    const Node* ref = nullptr;   // the <ref> element it came through, if any
    std::string name;            // the name attribute (may be empty for objects)
    bool isObject = false;
    bool used = false;

    const Node& site() const { return ref ? *ref : *node; }
};

class SceneBuilder;

enum class ColourUse { Reflectance, NonNegative };

class Props {
public:
    Props(SceneBuilder& builder, const Node& node, std::string kind);

    const Node& node() const { return node_; }
    const std::string& type() const { return type_; }
    std::string what() const { return kind_ + " " + inQuotes(type_); }
    const Version& version() const { return node_.version; }

    [[noreturn]] void fail(const Node& at, const std::string& message) const { fg::fail(at, what() + ": " + message); }
    [[noreturn]] void fail(const std::string& message) const { fail(node_, message); }

    bool has(std::string_view name) const { return findValue(name) != nullptr || findObject(name) != nullptr; }
    // Declares a parameter as understood without reading it ("accepted, no effect").
    void accept(std::string_view name, std::initializer_list<std::string_view> expectedTags) {
        if (Entry* e = value(name)) requireTag(*e, expectedTags);
    }

    std::optional<float> number(std::string_view name) {
        Entry* e = value(name);
        if (!e) return std::nullopt;
        requireTag(*e, {"float", "integer"});
        return parseScalar(*e);
    }
    float number(std::string_view name, float fallback) { return number(name).value_or(fallback); }

    std::optional<long long> integer(std::string_view name) {
        Entry* e = value(name);
        if (!e) return std::nullopt;
        requireTag(*e, {"integer"});
        const std::string& text = valueAttribute(*e);
        const std::optional<long long> v = parseInteger(text);
        if (!v) fail(*e->node, "parameter " + inQuotes(name) + ": " + inQuotes(text) + " is not an integer");
        return v;
    }

    std::optional<bool> boolean(std::string_view name) {
        Entry* e = value(name);
        if (!e) return std::nullopt;
        requireTag(*e, {"boolean"});
        std::string text(trim(valueAttribute(*e)));
        std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return std::tolower(c); });
        if (text == "true") return true;
        if (text == "false") return false;
        fail(*e->node, "parameter " + inQuotes(name) + ": " + inQuotes(text) + " is not true or false");
    }
    bool boolean(std::string_view name, bool fallback) { return boolean(name).value_or(fallback); }

    std::optional<std::string> string(std::string_view name) {
        Entry* e = value(name);
        if (!e) return std::nullopt;
        requireTag(*e, {"string"});
        return valueAttribute(*e);
    }

    std::optional<Vec3> vec3(std::string_view name) {
        Entry* e = value(name);
        if (!e) return std::nullopt;
        requireTag(*e, {"point", "vector"});
        return readVec3(*e->node, 0.0f, what());
    }

    std::optional<Rgb> colour(std::string_view name, ColourUse use);
    std::optional<Mat4> transform(std::string_view name);
    // The value element of a parameter, for callers that parse it themselves.
    const Node* valueNode(std::string_view name) {
        Entry* e = value(name);
        return e ? e->node : nullptr;
    }

    // Nested or referenced objects of one element type (bsdf, medium, ...), marked as read.
    std::vector<Entry*> objects(std::string_view tag) {
        std::vector<Entry*> result;
        for (Entry& e : entries_) {
            if (e.isObject && e.node->tag == tag) {
                e.used = true;
                result.push_back(&e);
            }
        }
        return result;
    }
    // At most one object of this element type.
    Entry* singleObject(std::string_view tag) {
        std::vector<Entry*> found = objects(tag);
        if (found.size() > 1) fail(found[1]->site(), "more than one <" + std::string(tag) + "> given");
        return found.empty() ? nullptr : found.front();
    }
    // A named object (textures bound to a parameter), marked as read.
    Entry* namedObject(std::string_view name) {
        Entry* e = findObject(name);
        if (e) e->used = true;
        if (std::find(known_.begin(), known_.end(), name) == known_.end()) known_.emplace_back(name);
        return e;
    }

    // Reports the first child nobody asked for.
    void finish() const {
        for (const Entry& e : entries_) {
            if (e.used) continue;
            if (e.isObject) {
                fail(e.site(), "unexpected <" + e.node->tag + ">" + (e.name.empty() ? "" : " named " + inQuotes(e.name)) +
                                   " (this plugin takes no such object)");
            }
            fail(e.site(), "unknown parameter " + inQuotes(e.name) +
                               (known_.empty() ? std::string(" (it takes none)") : " (expected: " + joinNames(known_) + ")"));
        }
    }

    static Vec3 readVec3(const Node& node, float fallbackComponent, const std::string& context);

private:
    Entry* value(std::string_view name) {
        if (std::find(known_.begin(), known_.end(), name) == known_.end()) known_.emplace_back(name);
        Entry* e = findValue(name);
        if (e) {
            e->used = true;
        } else if (Entry* object = findObject(name)) {
            fail(object->site(), "parameter " + inQuotes(name) + " cannot be given as a <" + object->node->tag + "> here");
        }
        return e;
    }
    Entry* findValue(std::string_view name) {
        for (Entry& e : entries_)
            if (!e.isObject && e.name == name) return &e;
        return nullptr;
    }
    const Entry* findValue(std::string_view name) const { return const_cast<Props*>(this)->findValue(name); }
    Entry* findObject(std::string_view name) {
        for (Entry& e : entries_)
            if (e.isObject && !e.name.empty() && e.name == name) return &e;
        return nullptr;
    }
    const Entry* findObject(std::string_view name) const { return const_cast<Props*>(this)->findObject(name); }

    void requireTag(const Entry& e, std::initializer_list<std::string_view> tags) const {
        if (std::find(tags.begin(), tags.end(), e.node->tag) != tags.end()) return;
        std::string list;
        for (std::string_view t : tags) list += (list.empty() ? "<" : " or <") + std::string(t) + ">";
        fail(*e.node, "parameter " + inQuotes(e.name) + " must be given as " + list + ", not <" + e.node->tag + ">");
    }
    const std::string& valueAttribute(const Entry& e) const {
        checkAttributes(*e.node, {"name", "value"}, what());
        return requireAttribute(*e.node, "value", what());
    }
    float parseScalar(const Entry& e) const {
        const std::string& text = valueAttribute(e);
        const std::optional<double> v = parseNumber(text);
        if (!v) fail(*e.node, "parameter " + inQuotes(e.name) + ": " + inQuotes(text) + " is not a number");
        return static_cast<float>(*v);
    }

    const Node& node_;
    std::string kind_;
    std::string type_;
    std::vector<Entry> entries_;
    std::vector<std::string> known_;
};

Vec3 Props::readVec3(const Node& node, float fallbackComponent, const std::string& context) {
    checkAttributes(node, {"name", "value", "x", "y", "z"}, context);
    const std::string* value = node.attribute("value");
    const bool hasXyz = node.attribute("x") || node.attribute("y") || node.attribute("z");
    if (value && hasXyz) fg::fail(node, prefix(context) + "<" + node.tag + "> takes either value=\"x, y, z\" or x, y, z attributes, not both");
    if (value) {
        const std::optional<std::vector<float>> v = parseNumberList(*value);
        if (!v || (v->size() != 3 && v->size() != 1)) {
            fg::fail(node, prefix(context) + "<" + node.tag + "> value " + inQuotes(*value) + " is not three numbers");
        }
        return v->size() == 1 ? Vec3((*v)[0]) : Vec3((*v)[0], (*v)[1], (*v)[2]);
    }
    Vec3 result(fallbackComponent);
    const char* axes[3] = {"x", "y", "z"};
    for (int i = 0; i < 3; ++i) {
        if (const std::string* a = node.attribute(axes[i])) {
            const std::optional<double> v = parseNumber(*a);
            if (!v) fg::fail(node, prefix(context) + "<" + node.tag + "> attribute " + axes[i] + "=" + inQuotes(*a) + " is not a number");
            result[i] = static_cast<float>(*v);
        }
    }
    return result;
}

// Spectrum values: one number (grey) or "wavelength:value" pairs with increasing wavelengths.
// On an emitter (`emission`), spectra convert as Mitsuba 3's RGB mode converts
// them (spectrum.h): no white balance, and a single value is not grey.
Rgb readSpectrum(const Node& node, const std::string& what, bool emission, bool* converted) {
    checkAttributes(node, {"name", "value", "filename", "intent"}, what);
    if (node.attribute("filename")) fail(node, what + ": spectra from files are not supported; give value=\"...\"");
    const std::string& text = requireAttribute(node, "value", what);
    *converted = false;
    if (text.find(':') == std::string::npos) {
        const std::optional<double> v = parseNumber(text);
        if (!v) {
            fail(node, what + ": spectrum " + inQuotes(text) +
                           " must be one number or wavelength:value pairs (e.g. \"400:0.2, 700:0.8\")");
        }
        if (emission) {
            *converted = *v >= 0.0;  // a negative value is reported as such, not clamped
            return uniformEmissionToRgb(static_cast<float>(*v));
        }
        return Rgb(static_cast<float>(*v));
    }
    std::vector<SpectrumSample> samples;
    std::stringstream stream(text);
    for (std::string item; std::getline(stream, item, ',');) {
        const auto colon = item.find(':');
        const std::optional<double> w = colon == std::string::npos ? std::nullopt : parseNumber(item.substr(0, colon));
        const std::optional<double> v = colon == std::string::npos ? std::nullopt : parseNumber(item.substr(colon + 1));
        if (!w || !v) fail(node, what + ": " + inQuotes(std::string(trim(item))) + " is not a wavelength:value pair");
        if (!(*w > 0.0)) fail(node, what + ": wavelength " + inQuotes(std::string(trim(item))) + " must be positive");
        if (!samples.empty() && !(*w > samples.back().wavelengthNm)) {
            fail(node, what + ": wavelengths must increase (" + inQuotes(std::string(trim(item))) + ")");
        }
        samples.push_back({static_cast<float>(*w), static_cast<float>(*v)});
    }
    if (samples.size() < 2) fail(node, what + ": a sampled spectrum needs at least two wavelength:value pairs");
    *converted = true;
    return emission ? emissionSpectrumToRgb(samples) : spectrumToRgb(samples);
}

std::optional<Rgb> Props::colour(std::string_view name, ColourUse use) {
    Entry* e = value(name);
    if (!e) return std::nullopt;
    const Node& n = *e->node;
    const std::string param = "parameter " + inQuotes(name);
    const std::string context = what() + ": " + param;
    Rgb c(0.0f);
    bool converted = false;
    if (n.tag == "float" || n.tag == "integer") {
        c = Rgb(parseScalar(*e));
    } else if (n.tag == "rgb" || n.tag == "srgb") {
        checkAttributes(n, {"name", "value", "intent"}, context);
        const std::string& text = requireAttribute(n, "value", context);
        const std::string_view t = trim(text);
        if (n.tag == "srgb" && !t.empty() && t.front() == '#') {
            unsigned value = 0;
            const auto [end, ec] = std::from_chars(t.data() + 1, t.data() + t.size(), value, 16);
            if (ec != std::errc() || end != t.data() + t.size() || t.size() != 7) {
                fail(n, param + ": " + inQuotes(text) + " is not a colour #rrggbb");
            }
            c = Rgb(static_cast<float>((value >> 16) & 0xff), static_cast<float>((value >> 8) & 0xff),
                    static_cast<float>(value & 0xff)) /
                255.0f;
        } else {
            const std::optional<std::vector<float>> v = parseNumberList(text);
            if (!v || (v->size() != 3 && v->size() != 1)) fail(n, param + ": " + inQuotes(text) + " is not an RGB triple");
            c = v->size() == 1 ? Rgb((*v)[0]) : Rgb((*v)[0], (*v)[1], (*v)[2]);
        }
        if (n.tag == "srgb") {
            if (!(c.x >= 0.0f && c.y >= 0.0f && c.z >= 0.0f && c.x <= 1.0f && c.y <= 1.0f && c.z <= 1.0f)) {
                fail(n, param + ": <srgb> components must lie in [0, 1]");
            }
            c = Rgb(srgbToLinear(c.x), srgbToLinear(c.y), srgbToLinear(c.z));
        }
    } else if (n.tag == "spectrum") {
        c = readSpectrum(n, context, kind_ == "emitter", &converted);
    } else {
        fail(n, param + " must be a colour (<rgb>, <srgb>, <spectrum> or <float>), not <" + n.tag + ">");
    }
    if (converted) {
        // Out-of-gamut spectra leave the RGB cube; clamp as Mitsuba does.
        c = glm::max(c, Rgb(0.0f));
        if (use == ColourUse::Reflectance) c = glm::min(c, Rgb(1.0f));
        return c;
    }
    if (!(c.x >= 0.0f && c.y >= 0.0f && c.z >= 0.0f)) fail(n, param + " must not be negative");
    if (use == ColourUse::Reflectance && !(c.x <= 1.0f && c.y <= 1.0f && c.z <= 1.0f)) {
        fail(n, param + " is a reflectance and must lie in [0, 1]");
    }
    return c;
}

Mat4 readTransformSteps(const Node& transform, const std::string& context) {
    checkAttributes(transform, {"name"}, context);
    Mat4 m(1.0f);
    for (const Node& step : transform.children) {
        Mat4 op(1.0f);
        if (step.tag == "translate") {
            op = glm::translate(Mat4(1.0f), Props::readVec3(step, 0.0f, context));
        } else if (step.tag == "scale") {
            const Vec3 s = Props::readVec3(step, 1.0f, context);
            if (s.x == 0.0f || s.y == 0.0f || s.z == 0.0f) fail(step, prefix(context) + "<scale> must not be zero");
            op = glm::scale(Mat4(1.0f), s);
        } else if (step.tag == "rotate") {
            checkAttributes(step, {"x", "y", "z", "value", "angle"}, context);
            Node axisNode = step;
            axisNode.attributes.erase(std::remove_if(axisNode.attributes.begin(), axisNode.attributes.end(),
                                                     [](const auto& a) { return a.first == "angle"; }),
                                      axisNode.attributes.end());
            const Vec3 axis = Props::readVec3(axisNode, 0.0f, context);
            if (!(glm::length(axis) > 0.0f)) fail(step, prefix(context) + "<rotate> needs a non-zero axis (x, y, z or value)");
            const std::string& angleText = requireAttribute(step, "angle", context);
            const std::optional<double> angle = parseNumber(angleText);
            if (!angle) fail(step, prefix(context) + "<rotate> angle " + inQuotes(angleText) + " is not a number");
            op = glm::rotate(Mat4(1.0f), glm::radians(static_cast<float>(*angle)), glm::normalize(axis));
        } else if (step.tag == "matrix") {
            checkAttributes(step, {"value"}, context);
            const std::string& text = requireAttribute(step, "value", context);
            const std::optional<std::vector<float>> v = parseNumberList(text);
            if (!v || v->size() != 16) fail(step, prefix(context) + "<matrix> value must be 16 numbers (row-major 4x4)");
            for (int row = 0; row < 4; ++row)
                for (int col = 0; col < 4; ++col) op[col][row] = (*v)[static_cast<std::size_t>(4 * row + col)];
            if (op[0][3] != 0.0f || op[1][3] != 0.0f || op[2][3] != 0.0f || op[3][3] != 1.0f) {
                fail(step, prefix(context) + "<matrix> must be affine: its last row must be 0 0 0 1");
            }
        } else if (step.tag == "lookat") {
            checkAttributes(step, {"origin", "target", "up"}, context);
            auto point = [&](std::string_view attr, const std::optional<Vec3>& fallback) -> Vec3 {
                const std::string* text = step.attribute(attr);
                if (!text) {
                    if (fallback) return *fallback;
                    fail(step, prefix(context) + "<lookat> needs the attribute " + inQuotes(attr));
                }
                const std::optional<std::vector<float>> v = parseNumberList(*text);
                if (!v || v->size() != 3) fail(step, prefix(context) + "<lookat> " + std::string(attr) + "=" + inQuotes(*text) + " is not three numbers");
                return {(*v)[0], (*v)[1], (*v)[2]};
            };
            const Vec3 origin = point("origin", std::nullopt);
            const Vec3 target = point("target", std::nullopt);
            const Vec3 up = point("up", Vec3(0.0f, 1.0f, 0.0f));
            if (!(glm::length(target - origin) > 0.0f)) fail(step, prefix(context) + "<lookat> target equals origin");
            const Vec3 dir = glm::normalize(target - origin);
            const Vec3 left = glm::cross(up, dir);
            if (!(glm::length(left) > 1e-6f * std::max(1.0f, glm::length(up)))) {
                fail(step, prefix(context) + "<lookat> up is parallel to the viewing direction" +
                               std::string(step.attribute("up") ? "" : " (give an up attribute)"));
            }
            const Vec3 x = glm::normalize(left);
            op[0] = Vec4(x, 0.0f);
            op[1] = Vec4(glm::cross(dir, x), 0.0f);
            op[2] = Vec4(dir, 0.0f);
            op[3] = Vec4(origin, 1.0f);
        } else {
            fail(step, prefix(context) + "unknown transform step <" + step.tag + "> (expected translate, scale, rotate, matrix or lookat)");
        }
        m = op * m;
    }
    const float det = glm::determinant(Mat3(m));
    if (!std::isfinite(det) || !(std::abs(det) > 1e-12f)) fail(transform, prefix(context) + "the transform is singular");
    return m;
}

std::optional<Mat4> Props::transform(std::string_view name) {
    Entry* e = value(name);
    if (!e) return std::nullopt;
    requireTag(*e, {"transform"});
    return readTransformSteps(*e->node, what());
}

// ---- meshes -----------------------------------------------------------------

// Angle-weighted vertex normals (Thuermer & Wuethrich 1998). A vertex whose
// faces cancel out leaves the mesh flat-shaded rather than with a bogus normal.
void computeVertexNormals(TriangleMesh& mesh) {
    std::vector<Vec3> sums(mesh.positions.size(), Vec3(0.0f));
    std::vector<bool> referenced(mesh.positions.size(), false);
    for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
        const std::uint32_t idx[3] = {mesh.indices[t], mesh.indices[t + 1], mesh.indices[t + 2]};
        const Vec3 n = glm::cross(mesh.positions[idx[1]] - mesh.positions[idx[0]], mesh.positions[idx[2]] - mesh.positions[idx[0]]);
        const float length = glm::length(n);
        if (!(length > 0.0f)) continue;
        for (int c = 0; c < 3; ++c) {
            const Vec3 e1 = mesh.positions[idx[(c + 1) % 3]] - mesh.positions[idx[c]];
            const Vec3 e2 = mesh.positions[idx[(c + 2) % 3]] - mesh.positions[idx[c]];
            const float l1 = glm::length(e1), l2 = glm::length(e2);
            if (!(l1 > 0.0f && l2 > 0.0f)) continue;
            const float angle = std::acos(std::clamp(glm::dot(e1, e2) / (l1 * l2), -1.0f, 1.0f));
            sums[idx[c]] += (angle / length) * n;
            referenced[idx[c]] = true;
        }
    }
    mesh.normals.assign(mesh.positions.size(), Vec3(0.0f, 0.0f, 1.0f));
    for (std::size_t v = 0; v < sums.size(); ++v) {
        if (!referenced[v]) continue;
        const float length = glm::length(sums[v]);
        if (!(length > 1e-12f) || !std::isfinite(length)) {
            mesh.normals.clear();
            return;
        }
        mesh.normals[v] = sums[v] / length;
    }
}

// ---- the scene builder ----------------------------------------------------------

class SceneBuilder {
public:
    SceneBuilder(Scene& scene, const FileResolver& resolver) : scene_(scene), resolver_(resolver) {}

    // Every top-level element is read even when an earlier one has a problem,
    // so that one load reports all of a scene's problems (up to kMaxProblems),
    // each as its own "file:line: plugin 'type': message" line.
    void build(const Node& root) {
        collectIds(root);
        bool sawSensor = false, sawIntegrator = false;
        for (const Node& child : root.children) {
            try {
                readTopLevel(child, sawSensor, sawIntegrator);
            } catch (const InputError& e) {
                record(e);
            }
        }
        if (!sawSensor) record(InputError(root.file->path, root.line, "the scene has no <sensor>"));
        // Groups nothing instantiates are still read, so that their errors show.
        for (const Node* group : shapeGroups_) {
            try {
                groupMembers(*group);
            } catch (const InputError& e) {
                record(e);
            }
        }
        if (problems_.size() == 1) throw firstProblem_.value();
        if (!problems_.empty()) throw InputError(problems_);
    }

    static constexpr std::size_t kMaxProblems = 50;

    void record(const InputError& e) {
        // A broken shared object (a bsdf with an id) is met again by every shape that uses it.
        const std::string message = e.what();
        if (std::find(problems_.begin(), problems_.end(), message) != problems_.end()) return;
        if (!firstProblem_) firstProblem_ = e;
        problems_.push_back(message);
        if (problems_.size() == kMaxProblems) {
            problems_.push_back("(stopped after " + std::to_string(kMaxProblems) + " problems)");
            throw InputError(problems_);
        }
    }

    void readTopLevel(const Node& child, bool& sawSensor, bool& sawIntegrator) {
        const std::string& tag = child.tag;
        if (tag == "sensor") {
            if (sawSensor) fail(child, "more than one <sensor>; fluxgraph renders one camera");
            sawSensor = true;
            readSensor(child);
        } else if (tag == "integrator") {
            if (sawIntegrator) fail(child, "more than one <integrator>");
            sawIntegrator = true;
            readIntegrator(child);
        } else if (tag == "shape") {
            readShape(child);
        } else if (tag == "emitter") {
            readTopLevelEmitter(child);
        } else if (tag == "bsdf" || tag == "texture" || tag == "medium" || tag == "phase") {
            if (!child.attribute("id")) {
                fail(child, "a top-level <" + tag + "> needs an id (shapes refer to it with <ref id=\"...\"/>)");
            }
            buildObject(child);
        } else if (kValueTags.count(tag) || tag == "ref") {
            fail(child, "<" + tag + "> is not allowed at the top level of a scene");
        } else if (tag == "volume") {
            fail(child, "heterogeneous medium not supported (<volume> grids are not implemented)");
        } else {
            fail(child, "unknown element <" + tag + ">");
        }
    }

    // Children of a plugin element, with <ref>s resolved.
    std::vector<Entry> entriesOf(const Node& node, const std::string& what) {
        std::vector<Entry> entries;
        for (const Node& child : node.children) {
            Entry e;
            if (child.tag == "ref") {
                checkAttributes(child, {"id", "name"});
                const std::string& id = requireAttribute(child, "id");
                const auto it = ids_.find(id);
                if (it == ids_.end()) fail(child, what + ": <ref> to unknown id " + inQuotes(id));
                e.node = it->second;
                e.ref = &child;
                e.isObject = true;
                if (const std::string* name = child.attribute("name")) e.name = *name;
            } else if (kValueTags.count(child.tag)) {
                const std::string* name = child.attribute("name");
                if (!name) fail(child, what + ": <" + child.tag + "> needs a name attribute");
                e.node = &child;
                e.name = *name;
            } else if (kObjectTags.count(child.tag)) {
                e.node = &child;
                e.isObject = true;
                if (const std::string* name = child.attribute("name")) e.name = *name;
            } else if (child.tag == "volume") {
                fail(child, what + ": heterogeneous medium not supported (<volume> grids are not implemented)");
            } else {
                fail(child, what + ": unknown element <" + child.tag + ">");
            }
            for (const Entry& other : entries) {
                if (!other.name.empty() && other.name == e.name) {
                    fail(e.site(), what + ": " + inQuotes(e.name) + " is given twice (first on line " +
                                       std::to_string(other.site().line) + ")");
                }
            }
            entries.push_back(e);
        }
        return entries;
    }

private:
    // ---- ids and shared objects ---------------------------------------------

    void collectIds(const Node& node) {
        for (const Node& child : node.children) {
            if (const std::string* id = child.attribute("id"); id && child.tag != "ref") {
                if (!kObjectTags.count(child.tag)) fail(child, "<" + child.tag + "> cannot have an id");
                const auto [it, inserted] = ids_.emplace(*id, &child);
                if (!inserted) {
                    fail(child, "id " + inQuotes(*id) + " is already used by the <" + it->second->tag + "> at " +
                                    it->second->file->path + ":" + std::to_string(it->second->line));
                }
            }
            collectIds(child);
        }
    }

    void buildObject(const Node& node) {
        if (node.tag == "bsdf") bsdfIndex(node);
        else if (node.tag == "texture") texture(node);
        else if (node.tag == "medium") mediumIndex(node);
        else if (node.tag == "phase") phaseG(node);
    }

    // Guards against objects that reach themselves through references.
    struct Building {
        Building(std::set<const Node*>& active, const Node& node) : active_(active), node_(&node) {
            if (!active_.insert(node_).second) {
                const std::string* type = node.attribute("type");
                const std::string* id = node.attribute("id");
                fail(node, node.tag + " " + inQuotes(type ? *type : "") + (id ? " (id " + inQuotes(*id) + ")" : "") +
                               " refers to itself through <ref>s");
            }
        }
        ~Building() { active_.erase(node_); }
        Building(const Building&) = delete;
        Building& operator=(const Building&) = delete;
        std::set<const Node*>& active_;
        const Node* node_;
    };

    const Node& expectObject(const Entry& e, std::string_view tag, const std::string& what) {
        if (e.node->tag != tag) {
            fail(e.site(), what + ": expected a <" + std::string(tag) + ">, but " +
                               (e.ref ? "the <ref> points to a <" + e.node->tag + ">" : "found a <" + e.node->tag + ">"));
        }
        return *e.node;
    }

    std::string resolveFile(Props& p, std::string_view key) {
        const std::optional<std::string> name = p.string(key);
        if (!name) p.fail("missing parameter " + inQuotes(key));
        const Node& at = *p.valueNode(key);
        const std::string path = resolver_.resolve(*name, at.file->directory);
        std::error_code ec;
        if (!fs::is_regular_file(path, ec)) p.fail(at, "file not found: " + path);
        return path;
    }

    // ---- integrator, sensor, film -------------------------------------------------

    // Mitsuba's max_depth counts the vertices of a path, the camera's included:
    // 1 shows emitters only, 2 is direct light, -1 is unlimited. fluxgraph's
    // max_depth counts scattering events (surface or medium), so it is one less;
    // -1 stays unlimited. Mitsuba's `direct` integrator has no max_depth and
    // renders exactly what max_depth = 2 renders.
    void readIntegrator(const Node& node) {
        checkAttributes(node, {"type", "id", "name"});
        // Only the depth is read; the job file chooses the algorithm. Wrapping
        // integrators (moment, aov) pass it on from the one they wrap.
        const Node* depthOwner = nullptr;
        const Node* depth = nullptr;
        std::vector<const Node*> stack = {&node};
        while (!stack.empty() && !depth) {
            const Node* n = stack.back();
            stack.pop_back();
            const std::string* type = n->attribute("type");
            if (type && (*type == "direct" || *type == "direct_projective")) {
                depthOwner = n;
                break;
            }
            for (const Node& child : n->children) {
                if (child.tag == "integer" && child.attribute("name") && *child.attribute("name") == "max_depth") {
                    depth = &child;
                    break;
                }
            }
            for (auto it = n->children.rbegin(); it != n->children.rend(); ++it)
                if (it->tag == "integrator") stack.push_back(&*it);
        }
        if (depthOwner) {
            scene_.hints.maxDepth = 1;
            return;
        }
        if (!depth) return;
        checkAttributes(*depth, {"name", "value"});
        const std::string& text = requireAttribute(*depth, "value");
        const std::optional<long long> v = parseInteger(text);
        if (!v || *v < -1 || *v > 100000) fail(*depth, "integrator max_depth " + inQuotes(text) + " must be an integer >= -1");
        if (*v == 0 || *v == 1) {
            fail(*depth, "integrator max_depth " + inQuotes(text) +
                             " is not supported: Mitsuba's max_depth counts the camera vertex, so " +
                             (*v == 0 ? "0 renders nothing" : "1 shows only emitters seen directly") +
                             "; fluxgraph renders at least one scattering event (max_depth >= 2)");
        }
        scene_.hints.maxDepth = *v < 0 ? -1 : static_cast<int>(*v) - 1;
    }

    void readSensor(const Node& node) {
        Props p(*this, node, "sensor");
        if (p.type() != "perspective" && p.type() != "orthographic") {
            p.fail("unknown sensor type (supported: perspective, orthographic)");
        }
        Camera& camera = scene_.camera;
        camera.width = 768;
        camera.height = 576;
        if (Entry* film = p.singleObject("film")) readFilm(expectObject(*film, "film", p.what()));
        if (Entry* sampler = p.singleObject("sampler")) readSampler(expectObject(*sampler, "sampler", p.what()));
        if (Entry* medium = p.singleObject("medium")) camera.medium = mediumIndex(expectObject(*medium, "medium", p.what()));
        if (p.type() == "orthographic") {
            readOrthographicSensor(p);
            return;
        }

        // Field of view, converted to the vertical angle fg::Camera uses.
        const bool hasFov = p.has("fov"), hasFocal = p.has("focal_length");
        if (hasFov && hasFocal) p.fail("give either fov or focal_length, not both");
        double fovDeg = 0.0;
        std::string axis = "x";
        if (hasFov) {
            fovDeg = p.number("fov", 0.0f);
            if (!(fovDeg > 0.0 && fovDeg < 180.0)) p.fail(*p.valueNode("fov"), "fov must lie in (0, 180) degrees");
            axis = p.string("fov_axis").value_or("x");
            std::transform(axis.begin(), axis.end(), axis.begin(), [](unsigned char c) { return std::tolower(c); });
        } else {
            if (p.has("fov_axis")) p.fail(*p.valueNode("fov_axis"), "fov_axis applies to fov only");
            std::string focal = p.string("focal_length").value_or("50mm");
            if (focal.size() > 2 && focal.compare(focal.size() - 2, 2, "mm") == 0) focal.resize(focal.size() - 2);
            const std::optional<double> mm = parseNumber(focal);
            if (!mm || !(*mm > 0.0)) p.fail(*p.valueNode("focal_length"), "focal_length must be a positive length like \"50mm\"");
            // 35 mm film: 36 x 24 mm, the angle spans its diagonal.
            fovDeg = 2.0 * std::atan(std::sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * *mm)) * 180.0 / std::numbers::pi;
            axis = "diagonal";
        }
        const double w = camera.width, h = camera.height;
        double axisLength = 0.0;
        if (axis == "x") axisLength = w;
        else if (axis == "y") axisLength = h;
        else if (axis == "diagonal") axisLength = std::sqrt(w * w + h * h);
        else if (axis == "smaller") axisLength = std::min(w, h);
        else if (axis == "larger") axisLength = std::max(w, h);
        else p.fail(*p.valueNode("fov_axis"), "fov_axis " + inQuotes(axis) + " must be x, y, diagonal, smaller or larger");
        const double tanHalfY = std::tan(0.5 * fovDeg * std::numbers::pi / 180.0) * h / axisLength;
        camera.fovYDegrees = static_cast<float>(2.0 * std::atan(tanHalfY) * 180.0 / std::numbers::pi);

        camera.nearClip = p.number("near_clip", 0.01f);
        camera.farClip = p.number("far_clip", 10000.0f);
        if (!(camera.nearClip >= 0.0f)) p.fail(*p.valueNode("near_clip"), "near_clip must not be negative");
        if (!(camera.farClip > camera.nearClip)) p.fail("far_clip must exceed near_clip");
        // A pinhole has no depth of field and the scene does not move.
        for (const char* key : {"focus_distance", "shutter_open", "shutter_close"}) p.accept(key, {"float", "integer"});
        for (const char* key : {"principal_point_offset_x", "principal_point_offset_y"}) {
            if (const std::optional<float> v = p.number(key); v && *v != 0.0f) {
                p.fail(*p.valueNode(key), std::string(key) + " is not supported (only 0)");
            }
        }

        const Mat4 m = p.transform("to_world").value_or(Mat4(1.0f));
        const Mat3 linear(m);
        const float scale = glm::length(linear[0]);
        float error = 0.0f;
        for (int i = 0; i < 3; ++i) {
            error += std::abs(glm::length(linear[i]) - scale);
            for (int j = i + 1; j < 3; ++j) error += std::abs(glm::dot(linear[i], linear[j]));
        }
        if (!(error <= 1e-3f * scale)) {
            p.fail(*p.valueNode("to_world"),
                   "the sensor's to_world may only rotate, translate, mirror and scale uniformly");
        }
        camera.eye = Vec3(m[3]);
        const Vec3 forward = glm::normalize(linear[2]);
        camera.target = camera.eye + forward;
        camera.up = glm::normalize(linear[1]);
        camera.mirrored = glm::determinant(linear) < 0.0f;
        // Clip distances are in the sensor's local units.
        camera.nearClip *= scale;
        if (camera.farClip < kInfinity) camera.farClip *= scale;
        p.finish();
    }

    // Mitsuba's orthographic sensor sees local x in [-1, 1] across the film's
    // width and y in [-1/aspect, 1/aspect] across its height, along local +z;
    // to_world's scale sets the extent in scene units.
    void readOrthographicSensor(Props& p) {
        Camera& camera = scene_.camera;
        camera.orthographic = true;
        camera.nearClip = p.number("near_clip", 0.01f);
        camera.farClip = p.number("far_clip", 10000.0f);
        if (!(camera.nearClip >= 0.0f)) p.fail(*p.valueNode("near_clip"), "near_clip must not be negative");
        if (!(camera.farClip > camera.nearClip)) p.fail("far_clip must exceed near_clip");
        for (const char* key : {"shutter_open", "shutter_close"}) p.accept(key, {"float", "integer"});

        const Mat4 m = p.transform("to_world").value_or(Mat4(1.0f));
        const Mat3 linear(m);
        const float scaleX = glm::length(linear[0]), scaleY = glm::length(linear[1]), scaleZ = glm::length(linear[2]);
        float skew = 0.0f;
        for (int i = 0; i < 3; ++i)
            for (int j = i + 1; j < 3; ++j) skew += std::abs(glm::dot(linear[i], linear[j])) / (glm::length(linear[i]) * glm::length(linear[j]));
        if (!(skew <= 1e-3f) || !(std::abs(scaleX - scaleY) <= 1e-3f * scaleX)) {
            p.fail(*p.valueNode("to_world"), "the orthographic sensor's to_world may rotate, translate, mirror and "
                                             "scale, with equal scales along its x and y axes");
        }
        camera.eye = Vec3(m[3]);
        camera.target = camera.eye + glm::normalize(linear[2]);
        camera.up = glm::normalize(linear[1]);
        camera.mirrored = glm::determinant(linear) < 0.0f;
        const float aspect = static_cast<float>(camera.width) / static_cast<float>(camera.height);
        camera.orthoHalfHeight = scaleY / aspect;
        camera.nearClip *= scaleZ;
        if (camera.farClip < kInfinity) camera.farClip *= scaleZ;
        p.finish();
    }

    void readFilm(const Node& node) {
        Props p(*this, node, "film");
        if (p.type() != "hdrfilm" && p.type() != "ldrfilm") {
            p.fail("unknown film type (supported: hdrfilm, ldrfilm)");
        }
        Camera& camera = scene_.camera;
        for (const char* key : {"width", "height"}) {
            const std::optional<long long> v = p.integer(key);
            if (!v) continue;
            if (*v < 1 || *v > 65536) p.fail(*p.valueNode(key), std::string(key) + " must lie in [1, 65536]");
            (std::string_view(key) == "width" ? camera.width : camera.height) = static_cast<int>(*v);
        }
        const std::optional<long long> cropX = p.integer("crop_offset_x"), cropY = p.integer("crop_offset_y");
        const std::optional<long long> cropW = p.integer("crop_width"), cropH = p.integer("crop_height");
        if (cropX.value_or(0) != 0 || cropY.value_or(0) != 0 || cropW.value_or(camera.width) != camera.width ||
            cropH.value_or(camera.height) != camera.height) {
            p.fail("crop windows are not supported");
        }
        // How the image is stored is the job's business.
        for (const char* key : {"file_format", "pixel_format", "component_format"}) p.accept(key, {"string"});
        for (const char* key : {"sample_border", "compensate", "banner", "high_quality_edges", "attach_log"}) p.accept(key, {"boolean"});
        if (p.type() == "ldrfilm") {
            p.accept("tonemap_method", {"string"});
            for (const char* key : {"gamma", "exposure", "key", "burn"}) p.accept(key, {"float", "integer"});
        }
        // Mitsuba's default reconstruction filter.
        RenderHints& hints = scene_.hints;
        hints.filter = FilterKind::Gaussian;
        hints.gaussianSigma = 0.5f;
        hints.filterRadius = 2.0f;
        if (Entry* filter = p.singleObject("rfilter")) readFilter(expectObject(*filter, "rfilter", p.what()));
        p.finish();
    }

    void readFilter(const Node& node) {
        Props p(*this, node, "rfilter");
        RenderHints& hints = scene_.hints;
        if (p.type() == "box") {
            hints.filter = FilterKind::Box;
            hints.filterRadius = p.number("radius", 0.5f);
            hints.gaussianSigma = 0.0f;
        } else if (p.type() == "gaussian") {
            hints.filter = FilterKind::Gaussian;
            hints.gaussianSigma = p.number("stddev", 0.5f);
            hints.filterRadius = 4.0f * hints.gaussianSigma;
        } else if (p.type() == "tent") {
            hints.filter = FilterKind::Tent;
            hints.filterRadius = p.number("radius", 1.0f);
            hints.gaussianSigma = 0.0f;
        } else {
            p.fail("unknown rfilter type (supported: box, gaussian, tent)");
        }
        if (!(hints.filterRadius > 0.0f && hints.filterRadius <= 16.0f)) p.fail("the filter radius must lie in (0, 16] pixels");
        p.finish();
    }

    void readSampler(const Node& node) {
        Props p(*this, node, "sampler");
        static const std::vector<std::string> kSamplers = {"independent", "stratified", "multijitter", "orthogonal",
                                                           "ldsampler", "halton", "hammersley", "sobol"};
        if (std::find(kSamplers.begin(), kSamplers.end(), p.type()) == kSamplers.end()) {
            p.fail("unknown sampler type (supported: " + joinNames(kSamplers) + ")");
        }
        if (const std::optional<long long> spp = p.integer("sample_count")) {
            if (*spp < 1 || *spp > (1ll << 30)) p.fail(*p.valueNode("sample_count"), "sample_count must be positive");
            scene_.hints.samplesPerPixel = static_cast<int>(*spp);
        }
        // Which random numbers are drawn does not change what is estimated.
        for (const char* key : {"seed", "scramble", "dimension"}) p.accept(key, {"integer"});
        p.accept("jitter", {"boolean"});
        p.finish();
    }

    // ---- bsdfs and textures -------------------------------------------------------

    int defaultBsdf() {
        if (defaultBsdf_ < 0) {
            defaultBsdf_ = static_cast<int>(scene_.bsdfs.size());
            scene_.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(0.5f))));
        }
        return defaultBsdf_;
    }

    int bsdfIndex(const Node& node) {
        if (const auto it = bsdfIndex_.find(&node); it != bsdfIndex_.end()) {
            noteAttributeReads(attributeReads_[it->second]);
            return it->second;
        }
        const Building guard(building_, node);
        Props p(*this, node, "bsdf");
        std::vector<const Node*> reads;
        std::shared_ptr<Bsdf> bsdf;
        {
            const CollectingAttributeReads collecting(attributeReadsBeingCollected_, reads);
            bsdf = makeBsdf(p);
            p.finish();
        }
        const int index = static_cast<int>(scene_.bsdfs.size());
        scene_.bsdfs.push_back(std::move(bsdf));
        bsdfIndex_[&node] = index;
        attributeReads_[index] = reads;
        noteAttributeReads(reads);
        return index;
    }

    // ---- mesh attributes ----------------------------------------------------------

    // While a bsdf is built, the mesh_attribute textures it reads (its nested
    // bsdfs' included) are collected, so that each shape using it can be
    // checked against its own mesh.
    struct CollectingAttributeReads {
        CollectingAttributeReads(std::vector<const Node*>*& slot, std::vector<const Node*>& reads)
            : slot_(slot), outer_(slot) {
            slot_ = &reads;
        }
        ~CollectingAttributeReads() { slot_ = outer_; }
        CollectingAttributeReads(const CollectingAttributeReads&) = delete;
        CollectingAttributeReads& operator=(const CollectingAttributeReads&) = delete;
        std::vector<const Node*>*& slot_;
        std::vector<const Node*>* outer_;
    };

    void noteAttributeReads(const std::vector<const Node*>& textures) {
        if (!attributeReadsBeingCollected_) return;
        for (const Node* t : textures) {
            std::vector<const Node*>& reads = *attributeReadsBeingCollected_;
            if (std::find(reads.begin(), reads.end(), t) == reads.end()) reads.push_back(t);
        }
    }

    static bool isMeshAttribute(const Node& textureNode) {
        const std::string* type = textureNode.attribute("type");
        return type && *type == "mesh_attribute";
    }

    // Textures outside materials (emitters, bump and normal maps) are looked up by uv alone.
    void refuseMeshAttribute(Props& p, const Node& textureNode, const Node& at, std::string_view use) {
        if (isMeshAttribute(textureNode)) p.fail(at, "a mesh_attribute texture cannot serve as " + std::string(use) + " (only as a material's parameter)");
    }

    // Every attribute the shape's material reads must be one of its mesh's.
    void checkMeshAttributes(Props& p, const Shape& shape) {
        for (const Node* textureNode : attributeReads_[shape.bsdf]) {
            const std::string& name = meshAttributeNames_.at(textureNode);
            const std::string site = "the mesh_attribute texture at " + textureNode->file->path + ":" + std::to_string(textureNode->line);
            const TriangleMesh* mesh = nullptr;
            if (const auto* instance = std::get_if<MeshInstance>(&shape.geometry)) mesh = instance->mesh.get();
            else mesh = std::get_if<TriangleMesh>(&shape.geometry);
            if (!mesh) p.fail("its bsdf reads the mesh attribute " + inQuotes(name) + " (" + site + "), but a sphere is not a mesh");
            if (mesh->attribute(name)) continue;
            std::vector<std::string> names;
            for (const MeshAttribute& a : mesh->attributes) names.push_back(a.name);
            p.fail("the mesh has no attribute " + inQuotes(name) + " (read by " + site + "); it has " +
                   (names.empty() ? std::string("none") : joinNames(names)));
        }
    }

    float readIor(Props& p, std::string_view key, float fallback) {
        const Node* n = p.valueNode(key);
        if (!n) return fallback;
        if (n->tag == "string") {
            const std::string name = *p.string(key);
            const std::optional<float> preset = dielectricIorPreset(name);
            if (!preset) p.fail(*n, "unknown index of refraction " + inQuotes(name));
            return *preset;
        }
        const float ior = *p.number(key);
        if (!(ior > 0.0f)) p.fail(*n, std::string(key) + " must be positive");
        return ior;
    }

    float relativeIor(Props& p, float interiorDefault) {
        const float interior = readIor(p, "int_ior", interiorDefault);
        const float exterior = readIor(p, "ext_ior", 1.000277f);  // Mitsuba's default: air
        return interior / exterior;
    }

    struct Roughness {
        float alpha;
        MicrofacetType type;
    };

    // Mitsuba's roughness parameters; sample_visible chooses only the sampling
    // strategy (fluxgraph always samples visible normals), so it is read and ignored.
    Roughness readRoughness(Props& p) {
        const std::string distribution = p.string("distribution").value_or("beckmann");
        const std::optional<MicrofacetType> type = microfacetTypeFromName(distribution);
        if (!type) {
            p.fail(*p.valueNode("distribution"), "distribution " + inQuotes(distribution) + " is not supported (ggx, beckmann)");
        }
        p.accept("sample_visible", {"boolean"});
        const bool hasAlpha = p.has("alpha"), hasU = p.has("alpha_u"), hasV = p.has("alpha_v");
        float alpha = 0.1f;
        if (hasAlpha && (hasU || hasV)) p.fail("give either alpha or alpha_u and alpha_v, not both");
        if (hasU != hasV) p.fail("alpha_u and alpha_v must be given together");
        if (hasU) {
            const float u = *p.number("alpha_u"), v = *p.number("alpha_v");
            if (u != v) p.fail(*p.valueNode("alpha_v"), "anisotropic roughness (alpha_u != alpha_v) is not supported");
            alpha = u;
        } else {
            alpha = p.number("alpha", 0.1f);
        }
        if (!(alpha > 0.0f && alpha <= 4.0f)) p.fail("alpha must lie in (0, 4]");
        return {alpha, *type};
    }

    Rgb specular(Props& p, std::string_view key) { return p.colour(key, ColourUse::Reflectance).value_or(Rgb(1.0f)); }

    void requireUnitSpecular(Props& p, std::string_view key) {
        if (const std::optional<Rgb> v = p.colour(key, ColourUse::Reflectance); v && *v != Rgb(1.0f)) {
            p.fail(*p.valueNode(key), std::string(key) + " other than 1 is not supported by " + p.what());
        }
    }

    ConductorIor readConductor(Props& p) {
        const bool hasMaterial = p.has("material"), hasEta = p.has("eta"), hasK = p.has("k");
        if (hasMaterial && (hasEta || hasK)) p.fail("give either material or eta and k, not both");
        if (hasEta != hasK) p.fail("eta and k must be given together");
        ConductorIor ior;
        if (hasEta) {
            ior.eta = *p.colour("eta", ColourUse::NonNegative);
            ior.k = *p.colour("k", ColourUse::NonNegative);
        } else {
            // Mitsuba 3 defaults to a perfect mirror, Mitsuba 0.x to copper.
            const std::string name = p.string("material").value_or(p.version().legacy() ? "Cu" : "none");
            const std::optional<ConductorIor> preset = conductorPreset(name);
            if (!preset) {
                p.fail(*p.valueNode("material"), "conductor material " + inQuotes(name) +
                                                     " is not available (supported: " + conductorNames() + ")");
            }
            ior = *preset;
        }
        const float extEta = readIor(p, "ext_eta", 1.0f);
        ior.eta /= extEta;
        ior.k /= extEta;
        return ior;
    }

    static std::string conductorNames() {
        std::string names;
        for (std::string_view name : conductorPresetNames()) names += (names.empty() ? "" : ", ") + std::string(name);
        return names;
    }

    std::shared_ptr<Bsdf> makeBsdf(Props& p) {
        const std::string& type = p.type();
        if (type == "diffuse") return makeDiffuse(textureParam(p, "reflectance", Rgb(0.5f)));
        if (type == "dielectric") {
            const float eta = relativeIor(p, 1.5046f);  // bk7
            auto reflectance = textureParam(p, "specular_reflectance", Rgb(1.0f));
            auto transmittance = textureParam(p, "specular_transmittance", Rgb(1.0f));
            return makeDielectric(eta, std::move(reflectance), std::move(transmittance));
        }
        if (type == "thindielectric") {
            const float eta = relativeIor(p, 1.5046f);
            requireUnitSpecular(p, "specular_reflectance");
            requireUnitSpecular(p, "specular_transmittance");
            return makeThinDielectric(eta);
        }
        if (type == "roughdielectric") {
            const float eta = relativeIor(p, 1.5046f);
            const Roughness roughness = readRoughness(p);
            requireUnitSpecular(p, "specular_reflectance");
            requireUnitSpecular(p, "specular_transmittance");
            return makeRoughDielectric(eta, roughness.alpha, roughness.type);
        }
        if (type == "conductor") {
            const ConductorIor ior = readConductor(p);
            return makeConductor(ior, textureParam(p, "specular_reflectance", Rgb(1.0f)));
        }
        if (type == "roughconductor") {
            const ConductorIor ior = readConductor(p);
            const Roughness roughness = readRoughness(p);
            return makeRoughConductor(ior, roughness.alpha, textureParam(p, "specular_reflectance", Rgb(1.0f)),
                                      roughness.type);
        }
        if (type == "plastic") {
            auto diffuse = textureParam(p, "diffuse_reflectance", Rgb(0.5f));
            const float eta = relativeIor(p, 1.49f);  // polypropylene
            requireUnitSpecular(p, "specular_reflectance");
            return makePlastic(std::move(diffuse), eta, p.boolean("nonlinear", false));
        }
        if (type == "roughplastic") {
            auto diffuse = textureParam(p, "diffuse_reflectance", Rgb(0.5f));
            const float eta = relativeIor(p, 1.49f);  // polypropylene
            const Roughness roughness = readRoughness(p);
            const Rgb specularReflectance = specular(p, "specular_reflectance");
            return makeRoughPlastic(std::move(diffuse), eta, roughness.alpha, roughness.type,
                                    p.boolean("nonlinear", false), specularReflectance);
        }
        if (type == "null") return makeNull();
        if (type == "mask" || type == "bumpmap" || type == "normalmap") return makeAdapterBsdf(p);
        if (type == "blendbsdf") return makeBlendBsdf(p);
        if (type == "principled") return makePrincipledBsdf(p);
        if (type == "principledthin") return makePrincipledThinBsdf(p);
        if (type == "twosided") {
            const std::vector<Entry*> inner = p.objects("bsdf");
            if (inner.size() != 1) {
                p.fail(inner.empty() ? p.node() : inner[1]->site(),
                       "twosided takes exactly one nested bsdf (different front and back materials are not supported)");
            }
            return makeTwoSided(scene_.bsdfs[static_cast<std::size_t>(bsdfIndex(*inner[0]->node))]);
        }
        p.fail("unknown bsdf type (supported: diffuse, dielectric, thindielectric, roughdielectric, conductor, roughconductor, "
               "plastic, roughplastic, principled, principledthin, null, twosided, mask, bumpmap, normalmap, blendbsdf)");
    }

    std::shared_ptr<Bsdf> makeBlendBsdf(Props& p) {
        if (!p.has("weight")) p.fail("missing parameter 'weight' (a float in [0, 1] or a texture)");
        const std::shared_ptr<Texture> weight = textureParam(p, "weight", Rgb(0.5f));
        const std::vector<Entry*> inner = p.objects("bsdf");
        if (inner.size() != 2) p.fail(inner.size() > 2 ? inner[2]->site() : p.node(), "takes exactly two nested bsdfs");
        std::shared_ptr<Bsdf> materials[2];
        for (int i = 0; i < 2; ++i) {
            materials[i] = scene_.bsdfs[static_cast<std::size_t>(bsdfIndex(*inner[i]->node))];
            if (materials[i]->perturbsNormal()) p.fail(inner[i]->site(), "blending bump- or normal-mapped materials is not supported");
        }
        return makeBlend(std::move(materials[0]), std::move(materials[1]), weight);
    }

    // Mitsuba 3's principled: scalar parameters left out or given as the
    // number 0 switch their lobe off, as Mitsuba's plugin does.
    std::shared_ptr<Bsdf> makePrincipledBsdf(Props& p) {
        PrincipledParameters parameters;
        parameters.baseColor = textureParam(p, "base_color", Rgb(0.5f));
        parameters.roughness = textureParam(p, "roughness", Rgb(0.5f));
        parameters.metallic = optionalTextureParam(p, "metallic");
        parameters.specTint = optionalTextureParam(p, "spec_tint");
        parameters.anisotropic = optionalTextureParam(p, "anisotropic");
        parameters.sheen = optionalTextureParam(p, "sheen");
        parameters.sheenTint = optionalTextureParam(p, "sheen_tint");
        parameters.clearcoat = optionalTextureParam(p, "clearcoat");
        parameters.clearcoatGloss = optionalTextureParam(p, "clearcoat_gloss");
        parameters.specTrans = optionalTextureParam(p, "spec_trans");
        parameters.flatness = optionalTextureParam(p, "flatness");
        const bool transmits = parameters.specTrans != nullptr;
        if (p.has("eta") && p.has("specular")) p.fail("give either eta or specular, not both");
        if (p.has("eta")) {
            parameters.eta = p.number("eta", 1.5f);
            if (!(parameters.eta > 0.0f)) p.fail(*p.valueNode("eta"), "eta must be positive");
            // An index-matched interface cannot refract; Mitsuba nudges it.
            if (transmits && parameters.eta == 1.0f) parameters.eta = 1.001f;
        } else {
            float specular = p.number("specular", 0.5f);
            if (!(specular >= 0.0f && specular < 12.5f)) {
                p.fail(*p.valueNode("specular"), "specular must be in [0, 12.5) (F0 = 0.08 specular)");
            }
            if (transmits && specular == 0.0f) specular = 1e-3f;
            parameters.eta = principledEtaFromSpecular(specular);
        }
        parameters.mainSpecularSamplingRate = p.number("main_specular_sampling_rate", 1.0f);
        parameters.clearcoatSamplingRate = p.number("clearcoat_sampling_rate", 1.0f);
        parameters.diffuseReflectanceSamplingRate = p.number("diffuse_reflectance_sampling_rate", 1.0f);
        return makePrincipled(std::move(parameters));
    }

    std::shared_ptr<Bsdf> makePrincipledThinBsdf(Props& p) {
        PrincipledThinParameters parameters;
        parameters.baseColor = textureParam(p, "base_color", Rgb(0.5f));
        parameters.roughness = textureParam(p, "roughness", Rgb(0.5f));
        parameters.eta = optionalTextureParam(p, "eta", ColourUse::NonNegative);
        if (!parameters.eta) {
            if (p.has("eta")) p.fail(*p.valueNode("eta"), "eta must be positive");
            parameters.eta = makeConstantTexture(Rgb(1.5f));
        }
        parameters.specTint = optionalTextureParam(p, "spec_tint");
        parameters.anisotropic = optionalTextureParam(p, "anisotropic");
        parameters.sheen = optionalTextureParam(p, "sheen");
        parameters.sheenTint = optionalTextureParam(p, "sheen_tint");
        parameters.specTrans = optionalTextureParam(p, "spec_trans");
        parameters.flatness = optionalTextureParam(p, "flatness");
        parameters.diffTrans = optionalTextureParam(p, "diff_trans", ColourUse::NonNegative);
        parameters.specularReflectanceSamplingRate = p.number("specular_reflectance_sampling_rate", 1.0f);
        parameters.specularTransmittanceSamplingRate = p.number("specular_transmittance_sampling_rate", 1.0f);
        parameters.diffuseReflectanceSamplingRate = p.number("diffuse_reflectance_sampling_rate", 1.0f);
        parameters.diffuseTransmittanceSamplingRate = p.number("diffuse_transmittance_sampling_rate", 1.0f);
        return makePrincipledThin(std::move(parameters));
    }

    // A parameter that may be a texture, or null where it is left out or the number 0.
    std::shared_ptr<Texture> optionalTextureParam(Props& p, std::string_view key, ColourUse use = ColourUse::Reflectance) {
        if (Entry* e = p.namedObject(key)) return texture(expectObject(*e, "texture", p.what() + " parameter " + inQuotes(key)));
        const std::optional<Rgb> value = p.colour(key, use);
        if (!value || *value == Rgb(0.0f)) return nullptr;
        return makeConstantTexture(*value);
    }

    // The one material a mask, bump map or normal map wraps.
    std::shared_ptr<Bsdf> nestedBsdf(Props& p) {
        const std::vector<Entry*> inner = p.objects("bsdf");
        if (inner.size() != 1) p.fail(inner.empty() ? p.node() : inner[1]->site(), "takes exactly one nested bsdf");
        return scene_.bsdfs[static_cast<std::size_t>(bsdfIndex(*inner[0]->node))];
    }

    // The one texture a bump or normal map reads, whatever its name.
    std::shared_ptr<Texture> nestedTexture(Props& p) {
        const std::vector<Entry*> found = p.objects("texture");
        if (found.size() != 1) p.fail(found.empty() ? p.node() : found[1]->site(), "takes exactly one nested texture");
        refuseMeshAttribute(p, *found[0]->node, found[0]->site(), "a bump or normal map");
        return texture(*found[0]->node);
    }

    std::shared_ptr<Bsdf> makeAdapterBsdf(Props& p) {
        if (p.type() == "mask") {
            auto opacity = textureParam(p, "opacity", Rgb(0.5f));
            return makeMask(nestedBsdf(p), std::move(opacity));
        }
        if (p.type() == "bumpmap") {
            // Newer Mitsuba 3 releases name the multiplier strength and take a
            // finite-difference step, epsilon; fluxgraph differentiates the texture exactly.
            if (p.has("scale") && p.has("strength")) p.fail("give either scale or strength, not both");
            const char* key = p.has("strength") ? "strength" : "scale";
            const float scale = p.number(key, 1.0f);
            if (!std::isfinite(scale)) p.fail(*p.valueNode(key), std::string(key) + " must be finite");
            p.accept("epsilon", {"float"});
            auto height = nestedTexture(p);
            return makeBumpMap(nestedBsdf(p), std::move(height), scale);
        }
        // normalmap: the texture is named "normalmap" in Mitsuba 3; an unnamed one is taken too.
        std::shared_ptr<Texture> normals;
        if (Entry* e = p.namedObject("normalmap")) {
            const Node& textureNode = expectObject(*e, "texture", p.what() + " parameter \"normalmap\"");
            refuseMeshAttribute(p, textureNode, e->site(), "a bump or normal map");
            normals = texture(textureNode);
        } else {
            normals = nestedTexture(p);
        }
        return makeNormalMap(nestedBsdf(p), std::move(normals));
    }

    // A reflectance that may be a texture: a constant value, or a nested / referenced <texture>.
    std::shared_ptr<Texture> textureParam(Props& p, std::string_view key, const Rgb& fallback) {
        if (Entry* e = p.namedObject(key)) return texture(expectObject(*e, "texture", p.what() + " parameter " + inQuotes(key)));
        return makeConstantTexture(p.colour(key, ColourUse::Reflectance).value_or(fallback));
    }

    // to_uv (Mitsuba 3: its 2x2 linear part and x, y translation act on uv) or
    // uscale/vscale/uoffset/voffset (0.x: uv * scale + offset).
    UvTransform uvTransform(Props& p) {
        UvTransform result;
        if (const std::optional<Mat4> m = p.transform("to_uv")) {
            const Mat4& t = *m;
            result.linear = glm::mat2(t[0][0], t[0][1], t[1][0], t[1][1]);
            result.offset = Vec2(t[3][0], t[3][1]);
        }
        if (p.version().legacy()) {
            const Vec2 scale(p.number("uscale", 1.0f), p.number("vscale", 1.0f));
            const Vec2 offset(p.number("uoffset", 0.0f), p.number("voffset", 0.0f));
            result = UvTransform{glm::mat2(scale.x, 0.0f, 0.0f, scale.y), offset}.after(result);
        }
        if (glm::determinant(result.linear) == 0.0f) {
            const Node* toUv = p.valueNode("to_uv");
            p.fail(toUv ? *toUv : p.node(), "texture coordinate transform must not be singular");
        }
        return result;
    }

    TextureWrap wrapMode(Props& p, std::string_view key, TextureWrap fallback) {
        const std::optional<std::string> mode = p.string(key);
        if (!mode) return fallback;
        if (*mode == "repeat") return TextureWrap::Repeat;
        if (*mode == "mirror") return TextureWrap::Mirror;
        if (*mode == "clamp") return TextureWrap::Clamp;
        p.fail(*p.valueNode(key), std::string(key) + " " + inQuotes(*mode) + " is not supported (repeat, mirror, clamp)");
    }

    BitmapLookup bitmapLookup(Props& p) {
        BitmapLookup lookup;
        std::string filter = p.string("filter_type").value_or("bilinear");
        // Mitsuba 0.x filters mip-mapped lookups; fluxgraph has one bilinear lookup.
        if (p.version().legacy() && (filter == "ewa" || filter == "trilinear")) filter = "bilinear";
        if (filter == "nearest") {
            lookup.filter = TextureFilter::Nearest;
        } else if (filter != "bilinear") {
            p.fail(*p.valueNode("filter_type"), "filter_type " + inQuotes(filter) + " is not supported (bilinear, nearest)");
        }
        const TextureWrap both = wrapMode(p, "wrap_mode", TextureWrap::Repeat);
        lookup.wrapU = wrapMode(p, "wrap_mode_u", both);
        lookup.wrapV = wrapMode(p, "wrap_mode_v", both);
        lookup.toUv = uvTransform(p);
        return lookup;
    }

    std::shared_ptr<Texture> texture(const Node& node) {
        if (const auto it = textures_.find(&node); it != textures_.end()) {
            if (isMeshAttribute(node)) noteAttributeReads({&node});
            return it->second;
        }
        const Building guard(building_, node);
        Props p(*this, node, "texture");
        std::shared_ptr<Texture> result;
        if (p.type() == "bitmap") {
            const std::string path = resolveFile(p, "filename");
            const bool raw = p.boolean("raw", false);
            const BitmapLookup lookup = bitmapLookup(p);
            RgbImage image;
            try {
                image = readRgbImage(path, raw);
            } catch (const InputError& e) {
                p.fail(*p.valueNode("filename"), e.what());
            }
            // Mitsuba puts v = 0 on the top image row, fluxgraph's bitmap on the bottom one.
            for (int y = 0; y < image.height / 2; ++y) {
                for (int x = 0; x < image.width; ++x) {
                    std::swap(image.pixels[static_cast<std::size_t>(y) * image.width + x],
                              image.pixels[static_cast<std::size_t>(image.height - 1 - y) * image.width + x]);
                }
            }
            textureResolution_[&node] = {image.width, image.height};
            result = makeBitmapTexture(std::move(image), lookup);
        } else if (p.type() == "checkerboard") {
            const Rgb color0 = p.colour("color0", ColourUse::Reflectance).value_or(Rgb(0.4f));
            const Rgb color1 = p.colour("color1", ColourUse::Reflectance).value_or(Rgb(0.2f));
            // Mitsuba's checkerboard has one checker per half unit of uv.
            result = makeCheckerboardTexture(color0, color1, UvTransform::scale(Vec2(2.0f)).after(uvTransform(p)));
        } else if (p.type() == "mesh_attribute") {
            result = readMeshAttribute(p);
        } else {
            p.fail("unknown texture type (supported: bitmap, checkerboard, mesh_attribute)");
        }
        p.finish();
        textures_[&node] = result;
        if (isMeshAttribute(node)) noteAttributeReads({&node});
        return result;
    }

    // Which mesh it reads is only known per shape: checkMeshAttributes.
    std::shared_ptr<Texture> readMeshAttribute(Props& p) {
        const std::optional<std::string> name = p.string("name");
        if (!name) p.fail("missing parameter 'name' (the mesh attribute to read, e.g. \"vertex_color\")");
        if (!name->starts_with("vertex_") && !name->starts_with("face_"))
            p.fail(*p.valueNode("name"), "name " + inQuotes(*name) + " must start with \"vertex_\" or \"face_\"");
        const float scale = p.number("scale", 1.0f);
        if (!std::isfinite(scale)) p.fail(*p.valueNode("scale"), "scale must be finite");
        meshAttributeNames_[&p.node()] = *name;
        return makeMeshAttributeTexture(*name, scale);
    }

    // ---- media ------------------------------------------------------------------

    float phaseG(const Node& node) {
        Props p(*this, node, "phase");
        float g = 0.0f;
        if (p.type() == "hg") {
            g = p.number("g", 0.8f);
            if (!(g > -1.0f && g < 1.0f)) p.fail(*p.valueNode("g"), "g must lie in (-1, 1)");
        } else if (p.type() != "isotropic") {
            p.fail("unknown phase function type (supported: isotropic, hg)");
        }
        p.finish();
        return g;
    }

    int mediumIndex(const Node& node) {
        if (const auto it = mediumIndex_.find(&node); it != mediumIndex_.end()) return it->second;
        const Building guard(building_, node);
        if (const std::string* type = node.attribute("type"); type && *type == "heterogeneous") {
            fail(node, "medium 'heterogeneous': heterogeneous medium not supported (only homogeneous media)");
        }
        Props p(*this, node, "medium");
        if (p.type() != "homogeneous") p.fail("unknown medium type (supported: homogeneous)");
        const bool extinctionForm = p.has("sigma_t") || p.has("albedo");
        const bool coefficientForm = p.has("sigma_s") || p.has("sigma_a");
        if (extinctionForm && coefficientForm) p.fail("give either sigma_t and albedo, or sigma_s and sigma_a");
        // Mitsuba 0.x falls back to a measured material preset, which fluxgraph does not have.
        if (p.version().legacy() && !extinctionForm && !coefficientForm) {
            p.fail("give sigma_t and albedo, or sigma_s and sigma_a (material presets are not supported)");
        }
        Rgb sigmaS, sigmaA;
        if (coefficientForm) {
            if (!p.has("sigma_s") || !p.has("sigma_a")) p.fail("sigma_s and sigma_a must be given together");
            sigmaS = *p.colour("sigma_s", ColourUse::NonNegative);
            sigmaA = *p.colour("sigma_a", ColourUse::NonNegative);
        } else {
            const Rgb sigmaT = p.colour("sigma_t", ColourUse::NonNegative).value_or(Rgb(1.0f));
            const Rgb albedo = p.colour("albedo", ColourUse::Reflectance).value_or(Rgb(0.75f));
            sigmaS = albedo * sigmaT;
            sigmaA = sigmaT - sigmaS;
        }
        const float scale = p.number("scale", 1.0f);
        if (!(scale > 0.0f)) p.fail(*p.valueNode("scale"), "scale must be positive");
        float g = 0.0f;
        if (Entry* phase = p.singleObject("phase")) g = phaseG(expectObject(*phase, "phase", p.what()));
        // Integrator-side switches in Mitsuba; they do not change the medium.
        p.accept("sample_emitters", {"boolean"});
        p.accept("has_spectral_extinction", {"boolean"});
        p.finish();
        const int index = static_cast<int>(scene_.media.size());
        scene_.media.emplace_back(sigmaA * scale, sigmaS * scale, g);
        mediumIndex_[&node] = index;
        return index;
    }

    // ---- shapes -----------------------------------------------------------------

    void finishMesh(Props& p, TriangleMesh& mesh, bool mayHaveFaceNormals) {
        if (const std::optional<Mat4> m = p.transform("to_world")) mesh.transform(*m);
        const bool faceNormals = mayHaveFaceNormals && p.boolean("face_normals", false);
        if (faceNormals) mesh.normals.clear();
        else if (mesh.normals.empty()) computeVertexNormals(mesh);
    }

    TriangleMesh readSerialized(Props& p) {
        const std::string path = resolveFile(p, "filename");
        const long long index = p.integer("shape_index").value_or(0);
        if (index < 0 || index > std::numeric_limits<int>::max()) p.fail(*p.valueNode("shape_index"), "shape_index must not be negative");
        try {
            return loadSerializedMesh(path, static_cast<int>(index));
        } catch (const InputError& e) {
            p.fail(*p.valueNode("filename"), e.what());
        }
    }

    // A shape group only defines its shapes; instances place copies of them.
    void readShapeGroup(Props& p) {
        if (!p.node().attribute("id")) p.fail("a shapegroup needs an id (instances refer to it)");
        if (p.objects("shape").empty()) p.fail("a shapegroup needs at least one <shape>");
        p.finish();
        shapeGroups_.push_back(&p.node());
    }

    // Every shape of the group, placed by the instance's to_world: meshes share
    // their data (MeshInstance; one Embree scene, instanced), analytic spheres
    // are copied with the transform folded in.
    void readInstance(Props& p) {
        Entry* group = p.singleObject("shape");
        if (!group || !group->ref) p.fail("an instance needs a <ref id=\"...\"/> to a shapegroup");
        const Node& groupNode = *group->node;
        const std::string* groupType = groupNode.attribute("type");
        if (!groupType || *groupType != "shapegroup") {
            p.fail(group->site(), "an instance must refer to a shapegroup, not a shape of type " +
                                      inQuotes(groupType ? *groupType : ""));
        }
        const Mat4 toWorld = p.transform("to_world").value_or(Mat4(1.0f));
        p.finish();
        instancedGroups_.insert(&groupNode);
        for (const GroupMember& member : groupMembers(groupNode)) {
            Shape shape = member.shape;
            if (auto* instance = std::get_if<MeshInstance>(&shape.geometry)) instance->toWorld = toWorld;
            else if (auto* sphere = std::get_if<Sphere>(&shape.geometry)) foldSphereTransform(p, group->site(), toWorld, *sphere);
            addShape(std::move(shape), member.emission);
        }
    }

    // Mitsuba's cylinder, as a tessellated open tube in object space (to_world follows).
    TriangleMesh readCylinder(Props& p) {
        const Vec3 p0 = p.vec3("p0").value_or(Vec3(0.0f));
        const Vec3 p1 = p.vec3("p1").value_or(Vec3(0.0f, 0.0f, 1.0f));
        const float radius = p.number("radius", 1.0f);
        if (!(radius > 0.0f) || !std::isfinite(radius)) p.fail(*p.valueNode("radius"), "radius must be positive");
        if (!(glm::length(p1 - p0) > 0.0f)) p.fail("p0 and p1 must differ");
        TriangleMesh mesh = makeCylinderMesh();
        mesh.transform(cylinderPlacement(p0, p1, radius));
        return mesh;
    }

    // A similarity (rotation, mirroring, uniform scale, translation) maps a sphere
    // onto a sphere; anything that stretches would make an ellipsoid, which the
    // analytic intersector does not represent.
    void foldSphereTransform(Props& p, const Node& at, const Mat4& m, Sphere& sphere) {
        const Mat3 linear(m);
        const float s = glm::length(linear[0]);
        float error = 0.0f;
        for (int i = 0; i < 3; ++i) {
            error += std::abs(glm::length(linear[i]) - s);
            for (int j = i + 1; j < 3; ++j) error += std::abs(glm::dot(linear[i], linear[j])) / s;
        }
        if (!(error <= 1e-4f * s)) {
            p.fail(at, "a sphere's to_world (and an instance's) may only rotate, translate and scale uniformly "
                       "(non-uniform scale would make an ellipsoid; use a mesh)");
        }
        sphere.center = Vec3(m * Vec4(sphere.center, 1.0f));
        sphere.radius *= s;
        // The inverse of a rotation times s is its transpose over s.
        sphere.worldToObject = sphere.worldToObject * (glm::transpose(linear) / s);
    }

    struct AreaEmission {
        Rgb radiance{1.0f};
        std::shared_ptr<Texture> texture;  // set when radiance is a texture
    };

    // A shape of a shape group, built once in the group's space; instances copy
    // it (a mesh as a MeshInstance of one shared mesh).
    struct GroupMember {
        Shape shape;
        std::optional<AreaEmission> emission;
    };

    // With `member`, the shape belongs to a shape group: it is returned there
    // instead of being added to the scene.
    void readShape(const Node& node, GroupMember* member = nullptr) {
        Props p(*this, node, "shape");
        Shape shape;
        const std::string& type = p.type();
        if (type == "shapegroup" || type == "instance") {
            if (member) p.fail("shape groups and instances cannot be nested in a shape group");
            if (type == "shapegroup") readShapeGroup(p);
            else readInstance(p);
            return;
        }
        const bool flip = p.boolean("flip_normals", false);
        if (type == "sphere") {
            Sphere sphere;
            sphere.center = p.vec3("center").value_or(Vec3(0.0f));
            sphere.radius = p.number("radius", 1.0f);
            if (!(sphere.radius > 0.0f)) p.fail(*p.valueNode("radius"), "radius must be positive");
            if (const std::optional<Mat4> m = p.transform("to_world")) foldSphereTransform(p, *p.valueNode("to_world"), *m, sphere);
            shape.geometry = sphere;
            shape.flipNormals = flip;
        } else {
            TriangleMesh mesh;
            bool faceNormalsParameter = false;
            if (type == "obj" || type == "ply") {
                const std::string path = resolveFile(p, "filename");
                try {
                    mesh = type == "obj" ? loadObjMesh(path) : loadPlyMesh(path);
                } catch (const InputError& e) {
                    p.fail(*p.valueNode("filename"), e.what());
                }
                // Mitsuba flips OBJ texture coordinates by default (v = 0 becomes the top row).
                if (type == "obj" && p.boolean("flip_tex_coords", true)) {
                    for (Vec2& uv : mesh.uvs) uv.y = 1.0f - uv.y;
                }
                faceNormalsParameter = true;
                shape.name = fs::path(path).stem().string();
            } else if (type == "rectangle") {
                mesh = makeRectangleMesh();
            } else if (type == "disk") {
                mesh = makeDiskMesh();
            } else if (type == "cube") {
                mesh = makeCubeMesh();
            } else if (type == "cylinder") {
                mesh = readCylinder(p);
            } else if (type == "serialized") {
                mesh = readSerialized(p);
                faceNormalsParameter = true;
            } else {
                p.fail("unknown shape type (supported: obj, ply, serialized, rectangle, disk, cube, cylinder, sphere, "
                       "shapegroup, instance)");
            }
            finishMesh(p, mesh, faceNormalsParameter);
            if (flip) mesh.flipNormals();
            if (member) shape.geometry = MeshInstance{std::make_shared<const TriangleMesh>(std::move(mesh)), Mat4(1.0f)};
            else shape.geometry = std::move(mesh);
        }
        if (const std::string* id = node.attribute("id")) shape.name = *id;
        if (shape.name.empty()) shape.name = type + std::to_string(scene_.shapes.size());

        const Entry* bsdf = p.singleObject("bsdf");
        shape.bsdf = bsdf ? bsdfIndex(expectObject(*bsdf, "bsdf", p.what())) : defaultBsdf();
        checkMeshAttributes(p, shape);
        for (Entry* medium : p.objects("medium")) {
            const Node& m = expectObject(*medium, "medium", p.what());
            int& slot = medium->name == "interior" ? shape.interiorMedium : shape.exteriorMedium;
            if (medium->name != "interior" && medium->name != "exterior") {
                p.fail(medium->site(), "a shape's medium must be named \"interior\" or \"exterior\"");
            }
            if (slot >= 0) p.fail(medium->site(), "the " + medium->name + " medium is given twice");
            slot = mediumIndex(m);
        }
        std::optional<AreaEmission> emission;
        if (const Entry* emitter = p.singleObject("emitter")) emission = areaRadiance(expectObject(*emitter, "emitter", p.what()), p);
        p.finish();
        if (member) {
            member->shape = std::move(shape);
            member->emission = emission;
            return;
        }
        addShape(std::move(shape), emission);
    }

    void addShape(Shape shape, const std::optional<AreaEmission>& emission) {
        const std::size_t index = scene_.shapes.size();
        if (emission && (emission->texture || !isBlack(emission->radiance))) {
            shape.areaLight = static_cast<int>(scene_.lights.size());
            scene_.lights.push_back(emission->texture ? makeTexturedAreaLight(shape, emission->texture)
                                                      : makeAreaLight(shape, emission->radiance));
            scene_.lightShape.push_back(static_cast<int>(index));
        }
        scene_.shapes.push_back(std::move(shape));
    }

    // The members of a shape group, built on first use.
    const std::vector<GroupMember>& groupMembers(const Node& group) {
        if (const auto it = groupMembers_.find(&group); it != groupMembers_.end()) return it->second;
        Props groupProps(*this, group, "shape");
        std::vector<GroupMember> members;
        for (Entry* entry : groupProps.objects("shape")) {
            GroupMember member;
            readShape(*entry->node, &member);
            members.push_back(std::move(member));
        }
        return groupMembers_[&group] = std::move(members);
    }

    // ---- emitters ---------------------------------------------------------------

    AreaEmission areaRadiance(const Node& node, const Props& shape) {
        if (const auto it = areaRadiance_.find(&node); it != areaRadiance_.end()) return it->second;
        Props p(*this, node, "emitter");
        if (p.type() != "area") shape.fail(node, "only area emitters can be attached to a shape, not " + p.what());
        AreaEmission emission;
        emission.texture = emissionTexture(p, "radiance");
        if (!emission.texture) emission.radiance = p.colour("radiance", ColourUse::NonNegative).value_or(Rgb(1.0f));
        p.finish();
        areaRadiance_[&node] = emission;
        return emission;
    }

    // A nested or referenced <texture> given for an emitter parameter, or null.
    std::shared_ptr<Texture> emissionTexture(Props& p, std::string_view key) {
        Entry* e = p.namedObject(key);
        if (!e) return nullptr;
        const Node& textureNode = expectObject(*e, "texture", p.what() + " parameter " + inQuotes(key));
        refuseMeshAttribute(p, textureNode, e->site(), "an emitter's " + inQuotes(key));
        return texture(textureNode);
    }

    // Mitsuba's projector: a pinhole's field of view (as the perspective sensor's,
    // over the irradiance texture's aspect ratio) and a texture it projects.
    std::shared_ptr<Light> readProjector(Props& p) {
        std::shared_ptr<Texture> irradiance = emissionTexture(p, "irradiance");
        int width = 1, height = 1;
        if (irradiance) {
            const Node& textureNode = *p.namedObject("irradiance")->node;
            if (const auto it = textureResolution_.find(&textureNode); it != textureResolution_.end()) {
                width = it->second.first;
                height = it->second.second;
            }
        } else {
            irradiance = makeConstantTexture(p.colour("irradiance", ColourUse::NonNegative).value_or(Rgb(1.0f)));
        }
        const double aspect = static_cast<double>(width) / height;
        const bool hasFov = p.has("fov"), hasFocal = p.has("focal_length");
        if (hasFov && hasFocal) p.fail("give either fov or focal_length, not both");
        double tanHalf = 0.0, axisOverX = 1.0;  // tan of half the angle along the axis, and that axis' length / width
        if (hasFov) {
            const double fov = p.number("fov", 0.0f);
            if (!(fov > 0.0 && fov < 180.0)) p.fail(*p.valueNode("fov"), "fov must lie in (0, 180) degrees");
            tanHalf = std::tan(0.5 * fov * std::numbers::pi / 180.0);
            std::string axis = p.string("fov_axis").value_or("x");
            if (axis == "y") axisOverX = 1.0 / aspect;
            else if (axis == "diagonal") axisOverX = std::sqrt(1.0 + 1.0 / (aspect * aspect));
            else if (axis == "smaller") axisOverX = std::min(1.0, 1.0 / aspect);
            else if (axis == "larger") axisOverX = std::max(1.0, 1.0 / aspect);
            else if (axis != "x") p.fail(*p.valueNode("fov_axis"), "fov_axis " + inQuotes(axis) + " must be x, y, diagonal, smaller or larger");
        } else {
            std::string focal = p.string("focal_length").value_or("50mm");
            if (focal.size() > 2 && focal.compare(focal.size() - 2, 2, "mm") == 0) focal.resize(focal.size() - 2);
            const std::optional<double> mm = parseNumber(focal);
            if (!mm || !(*mm > 0.0)) p.fail(*p.valueNode("focal_length"), "focal_length must be a positive length like \"50mm\"");
            tanHalf = std::sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * *mm);  // the 35 mm film's diagonal
            axisOverX = std::sqrt(1.0 + 1.0 / (aspect * aspect));
        }
        const float scale = p.number("scale", 1.0f);
        if (!(scale >= 0.0f) || !std::isfinite(scale)) p.fail(*p.valueNode("scale"), "scale must not be negative");
        const Mat4 m = p.transform("to_world").value_or(Mat4(1.0f));
        const Mat3 linear(m);
        const Mat3 shouldBeIdentity = glm::transpose(linear) * linear;
        float error = std::abs(std::abs(glm::determinant(linear)) - 1.0f);
        for (int c = 0; c < 3; ++c) error += glm::length(shouldBeIdentity[c] - Mat3(1.0f)[c]);
        if (error > 1e-3f) p.fail(*p.valueNode("to_world"), "a projector's to_world may only rotate and translate");
        return makeProjectorLight(m, std::move(irradiance), width, height, static_cast<float>(tanHalf / axisOverX), scale);
    }

    Vec3 positionOf(Props& p) {
        const bool hasPosition = p.has("position"), hasTransform = p.has("to_world");
        if (hasPosition && hasTransform) p.fail("give either position or to_world, not both");
        if (hasPosition) return *p.vec3("position");
        return Vec3(p.transform("to_world").value_or(Mat4(1.0f))[3]);
    }

    void readTopLevelEmitter(const Node& node) {
        Props p(*this, node, "emitter");
        const std::string& type = p.type();
        std::shared_ptr<Light> light;
        auto nonNegative = [&](std::string_view key) { return p.colour(key, ColourUse::NonNegative).value_or(Rgb(1.0f)); };
        if (type == "area") {
            if (!node.attribute("id")) p.fail("an area emitter must be inside a <shape> (or have an id that shapes refer to)");
            areaRadiance(node, p);
            return;  // a definition; shapes that refer to it become lights
        }
        if (type == "point") {
            const Vec3 position = positionOf(p);
            light = makePointLight(position, nonNegative("intensity"));
        } else if (type == "spot") {
            const Mat4 m = p.transform("to_world").value_or(Mat4(1.0f));
            const Vec3 axis = Vec3(m * Vec4(0.0f, 0.0f, 1.0f, 0.0f));
            const float cutoff = p.number("cutoff_angle", 20.0f);
            if (!(cutoff > 0.0f && cutoff < 180.0f)) p.fail(*p.valueNode("cutoff_angle"), "cutoff_angle must lie in (0, 180) degrees");
            const float beam = p.number("beam_width", 0.75f * cutoff);
            if (!(beam > 0.0f && beam <= cutoff)) p.fail(*p.valueNode("beam_width"), "beam_width must lie in (0, cutoff_angle]");
            if (std::shared_ptr<Texture> pattern = emissionTexture(p, "texture")) {
                if (!(cutoff < 90.0f)) p.fail(*p.valueNode("cutoff_angle"), "a textured spot's cutoff_angle must be below 90 degrees");
                light = makeTexturedSpotLight(m, nonNegative("intensity"), cutoff, beam, std::move(pattern));
            } else {
                light = makeSpotLight(Vec3(m[3]), glm::normalize(axis), nonNegative("intensity"), cutoff, beam);
            }
        } else if (type == "projector") {
            light = readProjector(p);
        } else if (type == "directional") {
            const bool hasDirection = p.has("direction"), hasTransform = p.has("to_world");
            if (hasDirection && hasTransform) p.fail("give either direction or to_world, not both");
            const Vec3 direction = hasDirection ? *p.vec3("direction")
                                                : Vec3(p.transform("to_world").value_or(Mat4(1.0f)) * Vec4(0.0f, 0.0f, 1.0f, 0.0f));
            if (!(glm::length(direction) > 0.0f)) p.fail("the direction must not be zero");
            light = makeDirectionalLight(glm::normalize(direction), nonNegative("irradiance"));
        } else if (type == "constant") {
            light = makeConstantEnvironment(nonNegative("radiance"));
        } else if (type == "envmap") {
            const std::string path = resolveFile(p, "filename");
            const float scale = p.number("scale", 1.0f);
            if (!(scale > 0.0f)) p.fail(*p.valueNode("scale"), "scale must be positive");
            Mat3 toWorld(1.0f);
            if (const std::optional<Mat4> m = p.transform("to_world")) {
                toWorld = Mat3(*m);
                const Mat3 shouldBeIdentity = glm::transpose(toWorld) * toWorld;
                float error = std::abs(glm::determinant(toWorld) - 1.0f) + glm::length(Vec3((*m)[3]));
                for (int c = 0; c < 3; ++c) error += glm::length(shouldBeIdentity[c] - Mat3(1.0f)[c]);
                if (error > 1e-3f) p.fail(*p.valueNode("to_world"), "an environment map's to_world may only rotate");
            }
            RgbImage image;
            try {
                image = readRgbImage(path);
            } catch (const InputError& e) {
                p.fail(*p.valueNode("filename"), e.what());
            }
            light = makeEnvironmentMap(image, scale, toWorld);
        } else {
            p.fail("unknown emitter type (supported: area, point, spot, projector, directional, constant, envmap)");
        }
        p.finish();
        scene_.lights.push_back(std::move(light));
        scene_.lightShape.push_back(-1);
    }

    Scene& scene_;
    const FileResolver& resolver_;
    std::unordered_map<std::string, const Node*> ids_;
    std::unordered_map<const Node*, int> bsdfIndex_;
    std::unordered_map<const Node*, int> mediumIndex_;
    std::unordered_map<const Node*, std::shared_ptr<Texture>> textures_;
    std::unordered_map<const Node*, std::string> meshAttributeNames_;  // mesh_attribute textures: the name they read
    std::unordered_map<int, std::vector<const Node*>> attributeReads_;  // per bsdf index: its mesh_attribute textures
    std::vector<const Node*>* attributeReadsBeingCollected_ = nullptr;
    std::unordered_map<const Node*, AreaEmission> areaRadiance_;
    std::unordered_map<const Node*, std::pair<int, int>> textureResolution_;  // bitmaps: width, height
    std::set<const Node*> building_;
    std::vector<const Node*> shapeGroups_;
    std::unordered_map<const Node*, std::vector<GroupMember>> groupMembers_;
    std::set<const Node*> instancedGroups_;
    int defaultBsdf_ = -1;
    std::vector<std::string> problems_;
    std::optional<InputError> firstProblem_;
};

Props::Props(SceneBuilder& builder, const Node& node, std::string kind) : node_(node), kind_(std::move(kind)) {
    checkAttributes(node, {"type", "id", "name"});
    const std::string* type = node.attribute("type");
    if (!type) fg::fail(node, "<" + node.tag + "> needs a type attribute");
    type_ = *type;
    entries_ = builder.entriesOf(node, what());
}

}  // namespace

Scene loadXmlScene(const std::string& path, const std::map<std::string, std::string>& defines) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) throw InputError(path, 0, "scene file not found");
    FileResolver resolver;
    const std::string dir = fs::path(path).parent_path().string();
    resolver.sceneDirectory = dir.empty() ? "." : dir;
    Preprocessor preprocessor(defines, resolver);
    const Node root = preprocessor.load(path);
    const std::vector<std::unique_ptr<SourceFile>> files = preprocessor.takeFiles();

    Scene scene;
    scene.sourcePath = path;
    SceneBuilder(scene, resolver).build(root);
    // Mitsuba's integrators pick every emitter with the same probability.
    scene.lightChoiceWeights.assign(scene.lights.size(), 1.0f);
    scene.finalize();
    return scene;
}

}  // namespace fg
