// Stanford PLY meshes (Turk 1994; ASCII, binary little- and big-endian), read
// here rather than through a library. Debian's only PLY reader was Assimp's,
// and fuzzing showed it unfit for files from elsewhere: it trusts the header
// (a missing end_header made it loop, a huge count allocate gigabytes, a list
// count of 40 digits 19 GB), and on one fuzzed file it corrupted the heap
// (AddressSanitizer's allocator found its own metadata overwritten). It also
// drops vertex colours. The format is small: a header of elements with typed
// scalar and list properties, then the records in that order.
//
// Every size is checked before it is used: the header must end within 64 KiB
// with a bare end_header, element counts must fit the file's size, and a list's
// items are read one by one (never reserved by their count), so a file can
// cost no more memory than its own size in vertices and indices. Polygons are
// fan-triangulated (as convex, like Mitsuba's loader does with quads); faces
// with fewer than three corners are errors. Normals and texture coordinates
// are kept when the vertex element has them; other scalar properties of the
// vertex and face elements become mesh attributes, grouped as Mitsuba 3's PLY
// loader groups them: red/green/blue (or r/g/b) are "color"; consecutive
// properties prefix_x/y/z, prefix_r/g/b (named prefix_color), prefix_0/1/2 or
// prefix_1/2/3 are one three-channel attribute and a lone prefix_x (r, 0, 1) a
// one-channel one; other groupings (two or four channels, alpha) and names
// without such a suffix are left out. Attribute names start with "vertex_" or
// "face_", as Mitsuba's mesh_attribute texture asks for them.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <optional>
#include <sstream>
#include <string_view>
#include <vector>

namespace fg {

namespace {

// Longer headers are not written by any exporter; the bound keeps a file
// without end_header from being scanned to its end as header text.
constexpr std::size_t kMaxHeaderBytes = 64 * 1024;

enum class PlyScalar { Int8, Uint8, Int16, Uint16, Int32, Uint32, Float32, Float64 };

// The PLY scalar types by name (both the 1994 names and the sized aliases).
std::optional<PlyScalar> scalarType(std::string_view type) {
    if (type == "char" || type == "int8") return PlyScalar::Int8;
    if (type == "uchar" || type == "uint8") return PlyScalar::Uint8;
    if (type == "short" || type == "int16") return PlyScalar::Int16;
    if (type == "ushort" || type == "uint16") return PlyScalar::Uint16;
    if (type == "int" || type == "int32") return PlyScalar::Int32;
    if (type == "uint" || type == "uint32") return PlyScalar::Uint32;
    if (type == "float" || type == "float32") return PlyScalar::Float32;
    if (type == "double" || type == "float64") return PlyScalar::Float64;
    return std::nullopt;
}

std::uint64_t scalarBytes(PlyScalar type) {
    switch (type) {
        case PlyScalar::Int8:
        case PlyScalar::Uint8: return 1;
        case PlyScalar::Int16:
        case PlyScalar::Uint16: return 2;
        case PlyScalar::Int32:
        case PlyScalar::Uint32:
        case PlyScalar::Float32: return 4;
        case PlyScalar::Float64: return 8;
    }
    return 1;
}

bool isInteger(PlyScalar type) { return type != PlyScalar::Float32 && type != PlyScalar::Float64; }

// The largest value of an unsigned integer type: colours stored as integers
// are fractions of it.
double integerRange(PlyScalar type) {
    switch (type) {
        case PlyScalar::Uint8: return 255.0;
        case PlyScalar::Uint16: return 65535.0;
        case PlyScalar::Uint32: return 4294967295.0;
        case PlyScalar::Int8: return 127.0;
        case PlyScalar::Int16: return 32767.0;
        case PlyScalar::Int32: return 2147483647.0;
        default: return 1.0;
    }
}

struct PlyProperty {
    std::string name;
    PlyScalar type = PlyScalar::Float32;  // of the items, for a list
    bool isList = false;
    PlyScalar countType = PlyScalar::Uint8;
};

struct PlyElement {
    std::string name;
    std::uint64_t count = 0;
    int line = 0;
    std::vector<PlyProperty> properties;

    // Bytes of a binary record's fixed part: its scalars and the count field of each list.
    std::uint64_t fixedBytes() const {
        std::uint64_t bytes = 0;
        for (const PlyProperty& p : properties) bytes += scalarBytes(p.isList ? p.countType : p.type);
        return bytes;
    }
    std::optional<std::size_t> find(std::string_view propertyName) const {
        for (std::size_t i = 0; i < properties.size(); ++i)
            if (properties[i].name == propertyName) return i;
        return std::nullopt;
    }
};

struct PlyHeader {
    bool ascii = false;
    bool bigEndian = false;
    std::vector<PlyElement> elements;
    std::size_t bodyOffset = 0;
};

// Parses the header of `data` (which starts with "ply") and checks that the
// element counts fit the file's size; throws an InputError naming path:line otherwise.
PlyHeader parsePlyHeader(const std::string& data, const std::string& path) {
    std::size_t position = 0;
    int line = 0;
    std::string format;
    PlyHeader header;
    bool ended = false;
    while (!ended) {
        const std::size_t newline = std::string_view(data).substr(0, kMaxHeaderBytes).find('\n', position);
        if (newline == std::string::npos) {
            throw InputError(path, 0, "PLY header has no end_header line" +
                                          std::string(data.size() > kMaxHeaderBytes ? " within its first 64 KiB" : ""));
        }
        ++line;
        std::string text = data.substr(position, newline - position);
        position = newline + 1;
        if (!text.empty() && text.back() == '\r') text.pop_back();
        std::istringstream words(text);
        std::string keyword;
        words >> keyword;
        const auto fail = [&](const std::string& message) { throw InputError(path, line, message); };
        if (line == 1) continue;  // "ply", checked by the caller
        if (keyword.empty() || keyword == "comment" || keyword == "obj_info") continue;
        std::vector<std::string> rest;
        for (std::string word; words >> word;) rest.push_back(word);
        if (keyword == "format") {
            if (!format.empty()) fail("PLY header has a second format line");
            if (rest.size() != 2) fail("PLY format line must be 'format <ascii|binary_little_endian|binary_big_endian> 1.0'");
            if (rest[0] != "ascii" && rest[0] != "binary_little_endian" && rest[0] != "binary_big_endian")
                fail("unknown PLY format '" + rest[0] + "' (expected ascii, binary_little_endian or binary_big_endian)");
            format = rest[0];
        } else if (keyword == "element") {
            if (rest.size() != 2) fail("PLY element line must be 'element <name> <count>'");
            PlyElement element;
            element.name = rest[0];
            element.line = line;
            const std::string& count = rest[1];
            const auto [end, error] = std::from_chars(count.data(), count.data() + count.size(), element.count);
            if (error == std::errc::result_out_of_range)
                fail("PLY element '" + element.name + "' has an impossibly large count " + count);
            if (error != std::errc() || end != count.data() + count.size())
                fail("PLY element '" + element.name + "' has a count that is not a non-negative integer: '" + count + "'");
            header.elements.push_back(element);
        } else if (keyword == "property") {
            if (header.elements.empty()) fail("PLY property before any element");
            PlyProperty property;
            if (!rest.empty() && rest[0] == "list") {
                if (rest.size() != 4) fail("PLY list property must be 'property list <count type> <item type> <name>'");
                const std::optional<PlyScalar> countType = scalarType(rest[1]);
                if (!countType || !isInteger(*countType))
                    fail("PLY list count type must be an integer type, not '" + rest[1] + "'");
                const std::optional<PlyScalar> itemType = scalarType(rest[2]);
                if (!itemType) fail("unknown PLY property type '" + rest[2] + "'");
                property = PlyProperty{rest[3], *itemType, true, *countType};
            } else {
                if (rest.size() != 2) fail("PLY property line must be 'property <type> <name>'");
                const std::optional<PlyScalar> type = scalarType(rest[0]);
                if (!type) fail("unknown PLY property type '" + rest[0] + "'");
                property = PlyProperty{rest[1], *type, false, PlyScalar::Uint8};
            }
            header.elements.back().properties.push_back(property);
        } else if (keyword == "end_header") {
            // Only a bare end_header (some parsers do not stop at end_header\v...).
            if (text.find_last_not_of(' ') + 1 != std::string_view("end_header").size() || text.find("end_header") != 0)
                fail("PLY end_header line must hold nothing else");
            ended = true;
        } else {
            fail("unexpected line in PLY header: '" + text + "'");
        }
    }
    if (format.empty()) throw InputError(path, 0, "PLY header has no format line");
    header.ascii = format == "ascii";
    header.bigEndian = format == "binary_big_endian";
    header.bodyOffset = position;

    // The smallest body the header allows: in binary the fixed part of every
    // record; in ASCII every value takes at least one character and a separator
    // (the last one may end the file without its separator).
    const std::uint64_t bodyBytes = data.size() - position;
    const std::uint64_t available = bodyBytes + (header.ascii ? 1 : 0);
    std::uint64_t needed = 0;
    for (const PlyElement& element : header.elements) {
        // An element without properties still counts a byte per record, so that
        // its count is bounded too.
        const std::uint64_t recordBytes =
            std::max<std::uint64_t>(1, header.ascii ? 2 * element.properties.size() : element.fixedBytes());
        if (element.count > available / recordBytes || needed + element.count * recordBytes > available) {
            throw InputError(path, element.line,
                             "PLY element '" + element.name + "' has " + std::to_string(element.count) +
                                 " records, more than the file's " + std::to_string(bodyBytes) + " bytes of data can hold");
        }
        needed += element.count * recordBytes;
    }
    return header;
}

// Reads the body's values one at a time, as text or as binary scalars of
// either byte order; every read is bounded by the end of the data.
class PlyBodyReader {
public:
    PlyBodyReader(std::string_view body, const PlyHeader& header, const std::string& path)
        : body_(body), ascii_(header.ascii), swap_(header.bigEndian != (std::endian::native == std::endian::big)),
          path_(path) {}

    void startRecord(const PlyElement& element, std::uint64_t record) {
        element_ = &element;
        record_ = record;
    }

    double scalar(PlyScalar type) { return ascii_ ? textValue(type) : binaryValue(type); }

    // A list's item count: a non-negative integer no larger than the number of
    // items the rest of the data could still hold.
    std::uint64_t listCount(PlyScalar countType, PlyScalar itemType) {
        const double count = scalar(countType);
        const std::uint64_t room = ascii_ ? (body_.size() - position_) / 2 + 1 : (body_.size() - position_) / scalarBytes(itemType);
        if (!(count >= 0.0) || count > static_cast<double>(room))
            fail("list count " + std::to_string(static_cast<long long>(count)) + " is more than the file can hold");
        return static_cast<std::uint64_t>(count);
    }

private:
    [[noreturn]] void fail(const std::string& what) const {
        throw InputError(path_, element_->line,
                         "cannot parse PLY file: element '" + element_->name + "' record " + std::to_string(record_) + ": " + what);
    }

    double textValue(PlyScalar type) {
        const auto isSpace = [](char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f'; };
        while (position_ < body_.size() && isSpace(body_[position_])) ++position_;
        if (position_ == body_.size()) fail("the file ends before its values do");
        const std::size_t start = position_;
        while (position_ < body_.size() && !isSpace(body_[position_])) ++position_;
        const std::string_view token = body_.substr(start, position_ - start);
        const auto printable = [&] {
            std::string shown;
            for (char c : token.substr(0, 24)) shown += (c >= 0x20 && c < 0x7f) ? c : '?';
            return "'" + shown + (token.size() > 24 ? "...'" : "'");
        };
        if (isInteger(type)) {
            long long value = 0;
            const auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
            if (error != std::errc() || end != token.data() + token.size()) fail(printable() + " is not an integer");
            return static_cast<double>(value);
        }
        double value = 0.0;
        const auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
        if (error != std::errc() || end != token.data() + token.size()) fail(printable() + " is not a number");
        return value;
    }

    template <typename T>
    T readBinary() {
        if (body_.size() - position_ < sizeof(T)) fail("the file ends before its values do");
        std::array<char, sizeof(T)> bytes;
        std::memcpy(bytes.data(), body_.data() + position_, sizeof(T));
        position_ += sizeof(T);
        if (swap_) std::reverse(bytes.begin(), bytes.end());
        return std::bit_cast<T>(bytes);
    }

    double binaryValue(PlyScalar type) {
        switch (type) {
            case PlyScalar::Int8: return readBinary<std::int8_t>();
            case PlyScalar::Uint8: return readBinary<std::uint8_t>();
            case PlyScalar::Int16: return readBinary<std::int16_t>();
            case PlyScalar::Uint16: return readBinary<std::uint16_t>();
            case PlyScalar::Int32: return readBinary<std::int32_t>();
            case PlyScalar::Uint32: return readBinary<std::uint32_t>();
            case PlyScalar::Float32: return readBinary<float>();
            case PlyScalar::Float64: return readBinary<double>();
        }
        return 0.0;
    }

    std::string_view body_;
    std::size_t position_ = 0;
    bool ascii_;
    bool swap_;
    const std::string& path_;
    const PlyElement* element_ = nullptr;
    std::uint64_t record_ = 0;
};

// Where the vertex attributes sit among the vertex element's properties.
struct VertexLayout {
    std::array<std::size_t, 3> position{};
    std::optional<std::array<std::size_t, 3>> normal;
    std::optional<std::array<std::size_t, 2>> uv;
    std::vector<std::string_view> names;  // of the properties above
};

template <std::size_t N>
std::optional<std::array<std::size_t, N>> findAll(const PlyElement& element, const std::array<std::string_view, N>& names) {
    std::array<std::size_t, N> found{};
    for (std::size_t i = 0; i < N; ++i) {
        const std::optional<std::size_t> index = element.find(names[i]);
        if (!index || element.properties[*index].isList) return std::nullopt;
        found[i] = *index;
    }
    return found;
}

VertexLayout vertexLayout(const PlyElement& vertices, const std::string& path) {
    VertexLayout layout;
    const auto position = findAll<3>(vertices, {"x", "y", "z"});
    if (!position) throw InputError(path, vertices.line, "PLY vertex element has no x, y and z properties");
    layout.position = *position;
    layout.normal = findAll<3>(vertices, {"nx", "ny", "nz"});
    // The names exporters use for texture coordinates, in order of preference.
    for (const auto& names : {std::array<std::string_view, 2>{"u", "v"}, std::array<std::string_view, 2>{"s", "t"},
                              std::array<std::string_view, 2>{"texture_u", "texture_v"},
                              std::array<std::string_view, 2>{"texture_s", "texture_t"}}) {
        if ((layout.uv = findAll<2>(vertices, names))) {
            layout.names.insert(layout.names.end(), names.begin(), names.end());
            break;
        }
    }
    layout.names.insert(layout.names.end(), {"x", "y", "z"});
    if (layout.normal) layout.names.insert(layout.names.end(), {"nx", "ny", "nz"});
    return layout;
}

// The properties one mesh attribute is read from (integers are fractions of their type's range).
struct AttributeLayout {
    std::string name;
    std::vector<std::size_t> properties;
};

// The attributes of an element (see the top of the file), skipping `reserved` properties.
std::vector<AttributeLayout> attributeLayouts(const PlyElement& element, const std::string& domain,
                                              const std::vector<std::string_view>& reserved) {
    std::vector<AttributeLayout> layouts;
    std::vector<bool> used(element.properties.size(), false);
    for (std::size_t i = 0; i < element.properties.size(); ++i) {
        const std::string& name = element.properties[i].name;
        used[i] = element.properties[i].isList || std::find(reserved.begin(), reserved.end(), name) != reserved.end();
    }
    for (const auto& names : {std::array<std::string_view, 3>{"red", "green", "blue"}, std::array<std::string_view, 3>{"r", "g", "b"}}) {
        const auto color = findAll<3>(element, names);
        if (!color) continue;
        if (layouts.empty()) layouts.push_back({domain + "color", {color->begin(), color->end()}});
        for (std::size_t index : *color) used[index] = true;
    }
    for (std::string_view alpha : {"alpha", "a"})
        if (const auto index = element.find(alpha)) used[*index] = true;

    // The channel suffixes of one attribute, in order.
    constexpr std::array<std::string_view, 4> kSuffixSchemes = {"xyzw", "rgba", "0123", "1234"};
    const auto split = [&](std::size_t index) -> std::optional<std::pair<std::string, char>> {
        const std::string& name = element.properties[index].name;
        const std::size_t underscore = name.rfind('_');
        if (underscore == std::string::npos || underscore == 0 || underscore + 2 != name.size()) return std::nullopt;
        return std::pair<std::string, char>(name.substr(0, underscore), name.back());
    };
    std::vector<std::string> prefixesSeen;
    for (std::size_t i = 0; i < element.properties.size();) {
        const auto first = used[i] ? std::nullopt : split(i);
        if (!first) {
            ++i;
            continue;
        }
        std::size_t scheme = 0;
        while (scheme < kSuffixSchemes.size() && kSuffixSchemes[scheme][0] != first->second) ++scheme;
        std::vector<std::size_t> group = {i};
        std::size_t next = i + 1;
        while (scheme < kSuffixSchemes.size() && next < element.properties.size() && group.size() < 4 && !used[next]) {
            const auto part = split(next);
            if (!part || part->first != first->first || part->second != kSuffixSchemes[scheme][group.size()]) break;
            group.push_back(next++);
        }
        i = next;
        const bool known = std::find(prefixesSeen.begin(), prefixesSeen.end(), first->first) != prefixesSeen.end();
        if (scheme == kSuffixSchemes.size() || known || (group.size() != 1 && group.size() != 3)) continue;
        prefixesSeen.push_back(first->first);
        layouts.push_back({domain + first->first + (scheme == 1 ? "_color" : ""), group});
    }
    return layouts;
}

// Starts one mesh attribute per layout; values follow as records are read.
std::vector<MeshAttribute> startAttributes(const std::vector<AttributeLayout>& layouts) {
    std::vector<MeshAttribute> attributes;
    for (const AttributeLayout& layout : layouts)
        attributes.push_back(MeshAttribute{layout.name, static_cast<int>(layout.properties.size()), {}});
    return attributes;
}

// Appends one record's values to each attribute, `copies` times (a polygon's triangles).
void appendAttributes(const PlyElement& element, const std::vector<AttributeLayout>& layouts,
                      const std::vector<double>& values, std::size_t copies, std::vector<MeshAttribute>& attributes) {
    for (std::size_t a = 0; a < layouts.size(); ++a) {
        for (std::size_t copy = 0; copy < copies; ++copy) {
            for (std::size_t property : layouts[a].properties) {
                const double scale = 1.0 / integerRange(element.properties[property].type);
                attributes[a].values.push_back(static_cast<float>(values[property] * scale));
            }
        }
    }
}

}  // namespace

TriangleMesh loadPlyMesh(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, 0, "PLY file not found");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "cannot open PLY file");
    const std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw InputError(path, 0, "cannot read PLY file");
    if (data.size() < 4 || data.compare(0, 3, "ply") != 0 || (data[3] != '\n' && data[3] != '\r')) {
        throw InputError(path, 0, "not a PLY file (it must start with the line 'ply')");
    }
    const PlyHeader header = parsePlyHeader(data, path);

    const PlyElement* vertexElement = nullptr;
    for (const PlyElement& element : header.elements)
        if (element.name == "vertex" && !vertexElement) vertexElement = &element;
    if (!vertexElement) throw InputError(path, 0, "PLY file has no vertex element");
    const VertexLayout layout = vertexLayout(*vertexElement, path);

    TriangleMesh mesh;
    const std::vector<AttributeLayout> vertexAttributes = attributeLayouts(*vertexElement, "vertex_", layout.names);
    std::vector<MeshAttribute> perVertex = startAttributes(vertexAttributes);
    const PlyElement* faceElement = nullptr;
    for (const PlyElement& element : header.elements)
        if (element.name == "face" && !faceElement) faceElement = &element;
    const std::vector<AttributeLayout> faceAttributes =
        faceElement ? attributeLayouts(*faceElement, "face_", {}) : std::vector<AttributeLayout>{};
    std::vector<MeshAttribute> perTriangle = startAttributes(faceAttributes);
    std::vector<double> values;
    std::vector<std::uint32_t> corners;
    PlyBodyReader reader(std::string_view(data).substr(header.bodyOffset), header, path);
    std::uint64_t faceCount = 0;
    for (const PlyElement& element : header.elements) {
        const bool isVertex = &element == vertexElement;
        const bool isFace = element.name == "face";
        // The face's list of corner indices; other elements have none.
        std::size_t indexList = element.properties.size();
        if (isFace) {
            std::optional<std::size_t> found = element.find("vertex_indices");
            if (!found) found = element.find("vertex_index");
            if (found && element.properties[*found].isList) indexList = *found;
        }
        values.resize(element.properties.size());
        for (std::uint64_t record = 0; record < element.count; ++record) {
            reader.startRecord(element, record);
            const std::size_t indicesBefore = mesh.indices.size();
            for (std::size_t p = 0; p < element.properties.size(); ++p) {
                const PlyProperty& property = element.properties[p];
                if (!property.isList) {
                    values[p] = reader.scalar(property.type);
                    continue;
                }
                const std::uint64_t items = reader.listCount(property.countType, property.type);
                const bool isIndices = p == indexList;
                if (isIndices) corners.clear();
                for (std::uint64_t item = 0; item < items; ++item) {
                    const double value = reader.scalar(property.type);
                    if (!isIndices) continue;
                    if (!(value >= 0.0) || value >= static_cast<double>(vertexElement->count))
                        throw InputError(path, element.line, "PLY face " + std::to_string(record) + " refers to a vertex that does not exist");
                    corners.push_back(static_cast<std::uint32_t>(value));
                }
                if (!isIndices) continue;
                if (corners.size() < 3) {
                    throw InputError(path, element.line, "face " + std::to_string(record) + " has " +
                                                             std::to_string(corners.size()) +
                                                             " corners; only polygon meshes are supported");
                }
                for (std::size_t c = 1; c + 1 < corners.size(); ++c) {
                    mesh.indices.push_back(corners[0]);
                    mesh.indices.push_back(corners[c]);
                    mesh.indices.push_back(corners[c + 1]);
                }
                ++faceCount;
            }
            if (&element == faceElement) {
                appendAttributes(element, faceAttributes, values, (mesh.indices.size() - indicesBefore) / 3, perTriangle);
            }
            if (!isVertex) continue;
            appendAttributes(element, vertexAttributes, values, 1, perVertex);
            const auto vec3 = [&](const std::array<std::size_t, 3>& at) {
                return Vec3(static_cast<float>(values[at[0]]), static_cast<float>(values[at[1]]),
                            static_cast<float>(values[at[2]]));
            };
            const Vec3 position = vec3(layout.position);
            if (!isFinite(position))
                throw InputError(path, element.line, "PLY file contains a vertex position that is not a finite number");
            mesh.positions.push_back(position);
            if (layout.normal) {
                const Vec3 normal = vec3(*layout.normal);
                const float length = glm::length(normal);
                mesh.normals.push_back(length > 0.0f ? normal / length : normal);
            }
            if (layout.uv)
                mesh.uvs.emplace_back(static_cast<float>(values[(*layout.uv)[0]]), static_cast<float>(values[(*layout.uv)[1]]));
        }
    }
    if (faceCount == 0 || mesh.indices.empty()) throw InputError(path, 0, "PLY file contains no faces");
    // A second face element would add triangles without values; such attributes are left out.
    const std::size_t counts[2] = {mesh.positions.size(), mesh.triangleCount()};
    std::vector<MeshAttribute>* domains[2] = {&perVertex, &perTriangle};
    for (int d = 0; d < 2; ++d) {
        for (MeshAttribute& attribute : *domains[d]) {
            if (attribute.values.size() == counts[d] * static_cast<std::size_t>(attribute.channels))
                mesh.attributes.push_back(std::move(attribute));
        }
    }
    return mesh;
}

}  // namespace fg
