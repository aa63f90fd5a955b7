// Job-file parsing with toml++. Command-line --set overrides are merged into
// the parsed tree before it is read, so they go through exactly the same checks
// as values written in the file; their messages name the --set argument.
#include "engine/core/job.h"

#include "engine/core/error.h"
#include "engine/core/text_input.h"

#include <toml++/toml.h>

#include <algorithm>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

namespace fg {

namespace {

namespace fs = std::filesystem;

class JobReader {
public:
    JobReader(std::string path, std::map<std::string, std::string> overrideSources)
        : path_(std::move(path)), overrideSources_(std::move(overrideSources)) {}

    // Where a node came from: "job.toml:12" or "--set passes.pt.spp=64".
    std::string source(const toml::node& node, const std::string& keyPath) const {
        if (const auto it = overrideSources_.find(keyPath); it != overrideSources_.end()) return it->second;
        const auto line = node.source().begin.line;
        if (line > 0) return path_ + ":" + std::to_string(line);
        // A table that is not in the file was made by an override of a key inside it.
        for (const auto& [key, origin] : overrideSources_)
            if (key.rfind(keyPath + ".", 0) == 0) return origin;
        return path_;
    }
    [[noreturn]] void fail(const toml::node& node, const std::string& keyPath, const std::string& message) const {
        throw InputError(source(node, keyPath) + ": " + message);
    }

    void checkKeys(const toml::table& table, const std::string& prefix, const std::set<std::string>& allowed) const {
        for (const auto& [key, node] : table) {
            if (!allowed.count(std::string(key.str()))) {
                std::string list;
                for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
                fail(node, prefix + std::string(key.str()),
                     "unknown key '" + prefix + std::string(key.str()) + "' (expected one of: " + list + ")");
            }
        }
    }

    std::string getString(const toml::table& t, const std::string& key, const std::string& keyPath,
                          const std::string& fallback) const {
        const toml::node* node = t.get(key);
        if (!node) return fallback;
        if (!node->is_string()) fail(*node, keyPath, "'" + keyPath + "' must be a string");
        return **node->as_string();
    }
    bool getBool(const toml::table& t, const std::string& key, const std::string& keyPath, bool fallback) const {
        const toml::node* node = t.get(key);
        if (!node) return fallback;
        if (!node->is_boolean()) fail(*node, keyPath, "'" + keyPath + "' must be true or false");
        return **node->as_boolean();
    }
    std::int64_t getInt(const toml::table& t, const std::string& key, const std::string& keyPath,
                        std::int64_t fallback, std::int64_t lo, std::int64_t hi) const {
        const toml::node* node = t.get(key);
        if (!node) return fallback;
        if (!node->is_integer()) fail(*node, keyPath, "'" + keyPath + "' must be an integer");
        const std::int64_t v = **node->as_integer();
        if (v < lo || v > hi) {
            fail(*node, keyPath, "'" + keyPath + "' = " + std::to_string(v) + " is outside [" + std::to_string(lo) +
                                     ", " + std::to_string(hi) + "]");
        }
        return v;
    }
    double getFloat(const toml::table& t, const std::string& key, const std::string& keyPath, double fallback,
                    double lo, double hi) const {
        const toml::node* node = t.get(key);
        if (!node) return fallback;
        double v = 0.0;
        if (node->is_integer()) v = static_cast<double>(**node->as_integer());
        else if (node->is_floating_point()) v = **node->as_floating_point();
        else fail(*node, keyPath, "'" + keyPath + "' must be a number");
        if (!(v >= lo && v <= hi)) {
            std::ostringstream msg;
            msg << "'" << keyPath << "' = " << v << " is outside [" << lo << ", " << hi << "]";
            fail(*node, keyPath, msg.str());
        }
        return v;
    }
    const toml::table* getTable(const toml::table& t, const std::string& key, const std::string& keyPath) const {
        const toml::node* node = t.get(key);
        if (!node) return nullptr;
        if (!node->is_table()) fail(*node, keyPath, "'" + keyPath + "' must be a table");
        return node->as_table();
    }

    ParamValue paramValue(const toml::node& node, const std::string& keyPath) const {
        if (node.is_integer()) return **node.as_integer();
        if (node.is_floating_point()) return **node.as_floating_point();
        if (node.is_boolean()) return **node.as_boolean();
        if (node.is_string()) return **node.as_string();
        fail(node, keyPath, "'" + keyPath + "' must be a number, boolean or string");
    }

    std::map<std::string, std::string> stringMap(const toml::table& t, const std::string& key,
                                                 const std::string& keyPath) const {
        std::map<std::string, std::string> out;
        const toml::table* table = getTable(t, key, keyPath);
        if (!table) return out;
        for (const auto& [k, v] : *table) {
            if (!v.is_string()) fail(v, keyPath + "." + std::string(k.str()), "buffer names must be strings");
            out[std::string(k.str())] = **v.as_string();
        }
        return out;
    }

    const std::string& path() const { return path_; }

private:
    std::string path_;
    std::map<std::string, std::string> overrideSources_;
};

// Shortest decimal text that reads back as the same double ("0.1", not "0.100000").
std::string shortestDecimal(double value) {
    char buffer[64];
    const auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
    return ec == std::errc() ? std::string(buffer, end) : std::to_string(value);
}

// Applies "a.b.c=value" to the tree; the value is parsed as a TOML value
// (numbers, booleans, quoted strings), a bare word is taken as a string.
void applyOverride(toml::table& root, const std::string& assignment) {
    const std::string origin = "--set " + assignment;
    const auto eq = assignment.find('=');
    if (eq == std::string::npos || eq == 0) throw InputError(origin + ": expected KEY=VALUE");
    const std::string keyPath = assignment.substr(0, eq);
    const std::string valueText = assignment.substr(eq + 1);
    toml::table parsedValue;
    try {
        parsedValue = toml::parse("v = " + valueText);
    } catch (const toml::parse_error&) {
        parsedValue = toml::table{{"v", valueText}};
    }
    std::vector<std::string> keys;
    std::stringstream stream(keyPath);
    for (std::string part; std::getline(stream, part, '.');) {
        if (part.empty()) throw InputError(origin + ": malformed key '" + keyPath + "'");
        keys.push_back(part);
    }
    toml::table* table = &root;
    for (std::size_t i = 0; i + 1 < keys.size(); ++i) {
        toml::node* next = table->get(keys[i]);
        if (!next) {
            table->insert(keys[i], toml::table{});
            next = table->get(keys[i]);
        }
        if (!next->is_table()) throw InputError(origin + ": '" + keys[i] + "' is not a table");
        table = next->as_table();
    }
    table->insert_or_assign(keys.back(), *parsedValue.get("v"));
}

// A [pipeline] table: passes in order, repeat blocks placed among them by
// where they stand in the file. `builtin` tables also carry a `doc`.
Pipeline readPipeline(const JobReader& r, const toml::table& t, const toml::node& at, bool builtin) {
    if (builtin) r.checkKeys(t, "pipeline.", {"name", "doc", "results", "pass", "repeat"});
    else r.checkKeys(t, "pipeline.", {"name", "results", "pass", "repeat"});
    Pipeline pipeline;
    pipeline.name = r.getString(t, "name", "pipeline.name", "custom");
    pipeline.doc = r.getString(t, "doc", "pipeline.doc", "");
    pipeline.results = {"image"};
    if (const toml::node* results = t.get("results")) {
        const toml::array* arr = results->as_array();
        if (!arr || arr->empty()) r.fail(*results, "pipeline.results", "'pipeline.results' must be a list of buffer names");
        pipeline.results.clear();
        for (const auto& v : *arr) {
            if (!v.is_string()) r.fail(v, "pipeline.results", "result names must be strings");
            pipeline.results.push_back(**v.as_string());
        }
    }
    const auto readNodes = [&](const toml::table& owner, const toml::node& where, const std::string& keyPath,
                               bool required) {
        std::vector<PipelineNode> nodes;
        const toml::node* passes = owner.get("pass");
        const toml::array* arr = passes ? passes->as_array() : nullptr;
        if (passes && !arr) r.fail(*passes, keyPath, "'" + keyPath + "' must be an array of tables ([[" + keyPath + "]])");
        if (required && (!arr || arr->empty()))
            r.fail(passes ? *passes : where, keyPath, "a pipeline needs [[" + keyPath + "]] entries");
        if (!arr) return nodes;
        for (const auto& entry : *arr) {
            if (!entry.is_table()) r.fail(entry, keyPath, "each [[" + keyPath + "]] must be a table");
            const toml::table& pt = *entry.as_table();
            r.checkKeys(pt, keyPath + ".", {"pass", "name", "inputs", "outputs"});
            PipelineNode node;
            node.pass = r.getString(pt, "pass", keyPath + ".pass", "");
            if (node.pass.empty()) r.fail(entry, keyPath, "[[" + keyPath + "]] needs 'pass = \"<registered pass>\"'");
            node.instance = r.getString(pt, "name", keyPath + ".name", node.pass);
            // Brackets are allowed in names: a pipeline may spell out a repeat block
            // by hand with its unrolled names ("train[0].photon") and random streams.
            if (node.instance.empty()) r.fail(entry, keyPath + ".name", "a pass instance name must not be empty");
            node.inputBindings = r.stringMap(pt, "inputs", keyPath + ".inputs");
            node.outputBindings = r.stringMap(pt, "outputs", keyPath + ".outputs");
            node.sourceLine = static_cast<int>(entry.source().begin.line);
            nodes.push_back(std::move(node));
        }
        return nodes;
    };
    const toml::node* repeats = t.get("repeat");
    pipeline.nodes = readNodes(t, at, "pipeline.pass", repeats == nullptr);
    if (repeats) {
        const toml::array* arr = repeats->as_array();
        if (!arr) r.fail(*repeats, "pipeline.repeat", "'pipeline.repeat' must be an array of tables ([[pipeline.repeat]])");
        for (const auto& entry : *arr) {
            if (!entry.is_table()) r.fail(entry, "pipeline.repeat", "each [[pipeline.repeat]] must be a table");
            const toml::table& bt = *entry.as_table();
            r.checkKeys(bt, "pipeline.repeat.", {"name", "count", "carry", "until", "seconds", "pass"});
            RepeatBlock block;
            block.name = r.getString(bt, "name", "pipeline.repeat.name", "");
            if (block.name.empty() || block.name.find_first_of("[]. ") != std::string::npos)
                r.fail(entry, "pipeline.repeat.name", "[[pipeline.repeat]] needs a plain 'name' (no dots, brackets or spaces)");
            block.count = static_cast<int>(r.getInt(bt, "count", "pipeline.repeat.count", 1, 1, 1000000));
            block.carry = r.stringMap(bt, "carry", "pipeline.repeat.carry");
            block.until = r.getString(bt, "until", "pipeline.repeat.until", "");
            block.seconds = r.getFloat(bt, "seconds", "pipeline.repeat.seconds", 0.0, 0.0, 1e9);
            block.nodes = readNodes(bt, entry, "pipeline.repeat.pass", true);
            block.sourceLine = static_cast<int>(entry.source().begin.line);
            block.position = static_cast<std::size_t>(std::count_if(
                pipeline.nodes.begin(), pipeline.nodes.end(),
                [&](const PipelineNode& n) { return n.sourceLine > 0 && n.sourceLine < block.sourceLine; }));
            pipeline.blocks.push_back(std::move(block));
        }
    }
    return pipeline;
}

}  // namespace

Pipeline parsePipelineFile(const std::string& text, const std::string& path) {
    toml::table root;
    try {
        root = toml::parse(text, path);
    } catch (const toml::parse_error& e) {
        throw InputError(path, static_cast<int>(e.source().begin.line), std::string(e.description()));
    }
    const JobReader r(path, {});
    r.checkKeys(root, "", {"pipeline"});
    const toml::table* table = r.getTable(root, "pipeline", "pipeline");
    if (!table) throw InputError(path + ": missing [pipeline] table");
    Pipeline pipeline = readPipeline(r, *table, root, true);
    pipeline.file = path;
    return pipeline;
}

Job parseJob(const std::string& text, const std::string& path, const JobOverrides& overrides,
             const Registry& registry) {
    toml::table root;
    try {
        root = toml::parse(text, path);
    } catch (const toml::parse_error& e) {
        throw InputError(path, static_cast<int>(e.source().begin.line), std::string(e.description()));
    }
    std::map<std::string, std::string> overrideSources;
    for (const std::string& assignment : overrides.sets) {
        applyOverride(root, assignment);
        overrideSources[assignment.substr(0, assignment.find('='))] = "--set " + assignment;
    }
    const JobReader r(path, overrideSources);

    Job job;
    job.path = path;
    job.text = text;
    job.overrides = overrides.sets;
    r.checkKeys(root, "", {"scene", "scene_defines", "pipeline", "seed", "threads", "stream_batches", "film", "output",
                           "passes", "import"});

    const toml::node* sceneNode = root.get("scene");
    if (!sceneNode) throw InputError(path + ": missing required key 'scene'");
    const std::string scene = r.getString(root, "scene", "scene", "");
    const fs::path jobDir = fs::path(path).parent_path();
    job.scenePath = fs::path(scene).is_absolute() ? scene : (jobDir / scene).lexically_normal().string();

    if (const toml::table* defines = r.getTable(root, "scene_defines", "scene_defines")) {
        for (const auto& [key, value] : *defines) {
            const std::string keyPath = "scene_defines." + std::string(key.str());
            std::string valueText;
            if (value.is_string()) valueText = **value.as_string();
            else if (value.is_integer()) valueText = std::to_string(**value.as_integer());
            else if (value.is_boolean()) valueText = **value.as_boolean() ? "true" : "false";
            else if (value.is_floating_point()) valueText = shortestDecimal(**value.as_floating_point());
            else r.fail(value, keyPath, "'" + keyPath + "' must be a string, number or boolean");
            job.sceneDefines[std::string(key.str())] = valueText;
        }
    }
    for (const std::string& define : overrides.defines) {
        const auto eq = define.find('=');
        if (eq == std::string::npos || eq == 0) throw InputError("--define " + define + ": expected NAME=VALUE");
        job.sceneDefines[define.substr(0, eq)] = define.substr(eq + 1);
    }

    job.seed = static_cast<std::uint64_t>(r.getInt(root, "seed", "seed", 1, 0, INT64_MAX));
    job.threads = static_cast<int>(r.getInt(root, "threads", "threads", 0, 0, kMaxThreads));
    if (overrides.seed) job.seed = *overrides.seed;
    if (overrides.threads) {
        if (*overrides.threads < 0 || *overrides.threads > kMaxThreads)
            throw InputError("--threads: must be 0 (all) or a count up to " + std::to_string(kMaxThreads));
        job.threads = *overrides.threads;
    }

    // Pipeline: a built-in name or a custom list.
    const toml::node* pipelineNode = root.get("pipeline");
    if (!pipelineNode) throw InputError(path + ": missing required key 'pipeline'");
    if (pipelineNode->is_string()) {
        const std::string name = **pipelineNode->as_string();
        const Pipeline* builtin = registry.findPipeline(name);
        if (!builtin) {
            std::string known;
            for (const auto& p : registry.pipelines) known += (known.empty() ? "" : ", ") + p.name;
            r.fail(*pipelineNode, "pipeline", "unknown pipeline '" + name + "' (built-in: " + known + ")");
        }
        job.pipeline = *builtin;
    } else if (pipelineNode->is_table()) {
        job.pipeline = readPipeline(r, *pipelineNode->as_table(), *pipelineNode, false);
    } else {
        r.fail(*pipelineNode, "pipeline", "'pipeline' must be a pipeline name or a [pipeline] table");
    }

    // Buffers read from files instead of being produced ([import] NAME = "path", --import).
    if (const toml::table* imports = r.getTable(root, "import", "import")) {
        for (const auto& [key, value] : *imports) {
            const std::string keyPath = "import." + std::string(key.str());
            if (!value.is_string()) r.fail(value, keyPath, "'" + keyPath + "' must be a file path");
            const std::string file = **value.as_string();
            job.bufferFiles.imports[std::string(key.str())] =
                fs::path(file).is_absolute() ? file : (jobDir / file).lexically_normal().string();
            job.bufferFiles.sources[std::string(key.str())] = r.source(value, keyPath);
        }
    }
    const auto bufferAssignment = [](const std::string& option, const std::string& assignment) {
        const auto eq = assignment.find('=');
        if (eq == std::string::npos || eq == 0 || eq + 1 == assignment.size())
            throw InputError(option + " " + assignment + ": expected NAME=PATH");
        return std::pair<std::string, std::string>(assignment.substr(0, eq), assignment.substr(eq + 1));
    };
    for (const std::string& assignment : overrides.imports) {
        const auto [name, file] = bufferAssignment("--import", assignment);
        job.bufferFiles.imports[name] = file;
        job.bufferFiles.sources[name] = "--import " + assignment;
    }
    for (const std::string& assignment : overrides.saves) {
        const auto [name, file] = bufferAssignment("--save", assignment);
        job.bufferFiles.saves[name] = file;
        job.bufferFiles.sources[name] = "--save " + assignment;
    }

    job.pipeline.streamBatches = r.getBool(root, "stream_batches", "stream_batches", true);

    if (const toml::table* film = r.getTable(root, "film", "film")) {
        r.checkKeys(*film, "film.", {"width", "height", "filter", "filter_radius", "gaussian_sigma"});
        const bool hasW = film->get("width") != nullptr, hasH = film->get("height") != nullptr;
        if (hasW != hasH) r.fail(*film, "film", "give both film.width and film.height, or neither");
        job.filmSizeGiven = hasW;
        job.filmFilterGiven = film->get("filter") != nullptr;
        job.film.width = static_cast<int>(r.getInt(*film, "width", "film.width", 256, 1, 16384));
        job.film.height = static_cast<int>(r.getInt(*film, "height", "film.height", 256, 1, 16384));
        const std::string filter = r.getString(*film, "filter", "film.filter", "box");
        if (filter == "box") {
            job.film.filter = FilterKind::Box;
            job.film.filterRadius = 0.5f;
        } else if (filter == "gaussian") {
            job.film.filter = FilterKind::Gaussian;
            job.film.filterRadius = 1.5f;
        } else if (filter == "tent") {
            job.film.filter = FilterKind::Tent;
            job.film.filterRadius = 1.0f;
        } else {
            r.fail(*film->get("filter"), "film.filter",
                   "film.filter must be \"box\", \"tent\" or \"gaussian\", not \"" + filter + "\"");
        }
        job.film.filterRadius = static_cast<float>(
            r.getFloat(*film, "filter_radius", "film.filter_radius", job.film.filterRadius, 0.01, 16.0));
        job.film.gaussianSigma = static_cast<float>(
            r.getFloat(*film, "gaussian_sigma", "film.gaussian_sigma", job.film.gaussianSigma, 0.01, 16.0));
    }

    job.output.name = fs::path(path).stem().string();
    if (const toml::table* out = r.getTable(root, "output", "output")) {
        r.checkKeys(*out, "output.", {"directory", "name", "exr", "png", "exposure", "half"});
        job.output.directory = r.getString(*out, "directory", "output.directory", job.output.directory);
        // An empty directory would otherwise surface at the end of a render as a
        // nameless "cannot create output directory".
        if (job.output.directory.empty())
            r.fail(*out->get("directory"), "output.directory", "output.directory must not be empty");
        job.output.name = r.getString(*out, "name", "output.name", job.output.name);
        // The name becomes part of a path: a '/' would reach into other directories,
        // a NUL would cut the path short, and "." or ".." name directories.
        const std::string& name = job.output.name;
        if (name.empty() || name == "." || name == ".." || name.find_first_of(std::string("/\0", 2)) != std::string::npos)
            r.fail(out->get("name") ? *out->get("name") : static_cast<const toml::node&>(*out), "output.name",
                   "output.name must be a plain file name (no '/', no NUL, not empty, not '.' or '..')");
        job.output.exr = r.getBool(*out, "exr", "output.exr", true);
        job.output.png = r.getBool(*out, "png", "output.png", true);
        job.output.exposure = static_cast<float>(r.getFloat(*out, "exposure", "output.exposure", 0.0, -64.0, 64.0));
        job.output.half = r.getBool(*out, "half", "output.half", false);
    }
    if (overrides.outputDirectory) job.output.directory = *overrides.outputDirectory;
    // Checked here, not when the images are written, so that validate catches it
    // and a render does not fail at its very end: file names are limited to 255
    // bytes, and the temporary name an image is first written to adds about 30.
    constexpr std::size_t kMaxOutputStemBytes = 200;
    for (const std::string& result : job.pipeline.results) {
        const std::string stem = job.pipeline.results.size() == 1 ? job.output.name : job.output.name + "-" + result;
        if (stem.size() <= kMaxOutputStemBytes) continue;
        const std::string message = "output file name '" + stem.substr(0, 40) + "...' is " + std::to_string(stem.size()) +
                                    " bytes long; output.name must keep it to " + std::to_string(kMaxOutputStemBytes);
        const toml::table* out = r.getTable(root, "output", "output");
        if (out && out->get("name")) r.fail(*out->get("name"), "output.name", message);
        throw InputError(path + ": " + message);
    }

    if (const toml::table* passes = r.getTable(root, "passes", "passes")) {
        for (const auto& [instanceKey, node] : *passes) {
            const std::string instance(instanceKey.str());
            const std::string prefix = "passes." + instance;
            if (!node.is_table()) r.fail(node, prefix, "'" + prefix + "' must be a table of parameters");
            job.params.tableSource[instance] = r.source(node, prefix);
            auto& values = job.params.values[instance];
            for (const auto& [paramKey, value] : *node.as_table()) {
                const std::string keyPath = prefix + "." + std::string(paramKey.str());
                values[std::string(paramKey.str())] = {r.paramValue(value, keyPath), r.source(value, keyPath)};
            }
        }
    }
    return job;
}

Job loadJob(const std::string& path, const JobOverrides& overrides, const Registry& registry) {
    return parseJob(readTextInput(path, "job file"), path, overrides, registry);
}

}  // namespace fg
