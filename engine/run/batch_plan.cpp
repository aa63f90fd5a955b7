// Reading batch plans with toml++ and expanding them into runs. Everything
// that can be wrong with a plan is found here, before the first render, and
// reported as one line naming the plan file and line.
#include "engine/run/batch_plan.h"

#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/pass.h"
#include "engine/core/scheduler.h"
#include "engine/core/text_input.h"

#include <toml++/toml.h>

#include <glob.h>

#include <charconv>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

namespace fg {

namespace {

namespace fs = std::filesystem;

std::string where(const std::string& path, const toml::node& node) {
    const auto line = node.source().begin.line;
    return line > 0 ? path + ":" + std::to_string(line) : path;
}

[[noreturn]] void fail(const std::string& path, const toml::node& node, const std::string& message) {
    throw InputError(where(path, node) + ": " + message);
}

void checkKeys(const std::string& path, const toml::table& table, const std::string& prefix,
               const std::set<std::string>& allowed) {
    for (const auto& [key, node] : table) {
        if (allowed.count(std::string(key.str()))) continue;
        std::string list;
        for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
        fail(path, node, "unknown key '" + prefix + std::string(key.str()) + "' (expected one of: " + list + ")");
    }
}

std::string shortestDecimal(double value) {
    char buffer[64];
    const auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
    return ec == std::errc() ? std::string(buffer, end) : std::to_string(value);
}

// A --set value as TOML text (what applyOverride parses) and as it reads in a file name.
struct SetValue {
    std::string toml;
    std::string plain;
};

SetValue setValue(const std::string& path, const toml::node& node, const std::string& key) {
    if (node.is_integer()) {
        const std::string text = std::to_string(**node.as_integer());
        return {text, text};
    }
    if (node.is_floating_point()) {
        const std::string text = shortestDecimal(**node.as_floating_point());
        return {text, text};
    }
    if (node.is_boolean()) {
        const std::string text = **node.as_boolean() ? "true" : "false";
        return {text, text};
    }
    if (node.is_string()) {
        std::ostringstream quoted;
        quoted << toml::value<std::string>(**node.as_string());
        return {quoted.str(), **node.as_string()};
    }
    fail(path, node, "'" + key + "': a set value must be a number, boolean or string");
}

// Keeps file names portable and free of shell trouble.
std::string sanitise(const std::string& text) {
    std::string out;
    for (char c : text) {
        const bool plain = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' ||
                           c == '_' || c == '.' || c == '=' || c == '+';
        out += plain ? c : '_';
    }
    return out;
}

// The job's path relative to the plan directory, extension dropped, '/' -> '-':
// stable when other entries are added to the plan, unlike a shortest unique name.
std::string jobStem(const fs::path& planDir, const std::string& jobPath) {
    fs::path relative = fs::path(jobPath).lexically_relative(planDir);
    if (relative.empty() || *relative.begin() == "..") relative = fs::path(jobPath).filename();
    relative.replace_extension();
    std::string stem;
    for (const auto& part : relative) {
        if (!stem.empty()) stem += '-';  // appended separately: GCC 12 warns (-Wrestrict, falsely) on "-" + string
        stem += part.string();
    }
    return sanitise(stem);
}

// Job files matching `pattern` (relative to the plan directory), sorted.
std::vector<std::string> expandGlob(const std::string& planPath, const toml::node& node, const fs::path& planDir,
                                    const std::string& pattern) {
    const std::string full = fs::path(pattern).is_absolute() ? pattern : (planDir / pattern).lexically_normal().string();
    if (full.find_first_of("*?[") == std::string::npos) return {full};
    glob_t matches{};
    const int status = ::glob(full.c_str(), 0, nullptr, &matches);
    std::vector<std::string> paths;
    if (status == 0)
        for (std::size_t i = 0; i < matches.gl_pathc; ++i) paths.emplace_back(matches.gl_pathv[i]);
    ::globfree(&matches);
    if (paths.empty()) fail(planPath, node, "'" + pattern + "' matches no file");
    return paths;
}

struct NamedSet {
    std::string key;
    std::vector<SetValue> values;
    std::string origin;
};

std::vector<NamedSet> readSetTable(const std::string& path, const toml::node& node, const std::string& keyPath,
                                   bool listsAllowed) {
    const toml::table* table = node.as_table();
    if (!table) fail(path, node, "'" + keyPath + "' must be a table of KEY = value" + (listsAllowed ? "s" : ""));
    std::vector<NamedSet> sets;
    for (const auto& [key, value] : *table) {
        NamedSet set{std::string(key.str()), {}, where(path, value)};
        if (const toml::array* list = value.as_array()) {
            if (!listsAllowed)
                fail(path, value, "'" + keyPath + "." + set.key + "': plan-wide values are single values; sweep in [[sweep]]");
            if (list->empty()) fail(path, value, "'" + keyPath + "." + set.key + "' is an empty list: the sweep has no runs");
            for (const auto& element : *list) set.values.push_back(setValue(path, element, set.key));
        } else {
            set.values.push_back(setValue(path, value, set.key));
        }
        sets.push_back(std::move(set));
    }
    return sets;
}

std::string runOrigin(const BatchRun& run, const std::string& message) {
    // Problems caused by a --set value point at the line that wrote it.
    if (message.rfind("--set ", 0) == 0) {
        const std::string assignment = message.substr(6, message.find(':', 6) - 6);
        const std::string key = assignment.substr(0, assignment.find('='));
        if (const auto it = run.setOrigins.find(key); it != run.setOrigins.end()) return it->second;
    }
    return run.origin;
}

}  // namespace

BatchPlan parseBatchPlan(const std::string& text, const std::string& path) {
    toml::table root;
    try {
        root = toml::parse(text, path);
    } catch (const toml::parse_error& e) {
        throw InputError(path, static_cast<int>(e.source().begin.line), std::string(e.description()));
    }
    checkKeys(path, root, "", {"output", "jobs", "set", "sweep"});
    const fs::path planDir = fs::path(path).parent_path();

    BatchPlan plan;
    plan.path = path;
    const toml::node* output = root.get("output");
    if (!output) throw InputError(path + ": missing required key 'output' (the directory for images and results)");
    if (!output->is_string() || output->as_string()->get().empty())
        fail(path, *output, "'output' must be a directory name");
    plan.outputDirectory = **output->as_string();

    std::vector<NamedSet> planSets;
    if (const toml::node* set = root.get("set")) planSets = readSetTable(path, *set, "set", false);

    const auto addRun = [&](const std::string& jobPath, const std::string& origin, const std::string& reference,
                            const std::vector<std::pair<const NamedSet*, const SetValue*>>& swept) {
        BatchRun run;
        run.jobPath = jobPath;
        run.origin = origin;
        run.referencePath = reference;
        run.name = jobStem(planDir, jobPath);
        for (const NamedSet& s : planSets) {
            run.sets.push_back(s.key + "=" + s.values.front().toml);
            run.setOrigins[s.key] = s.origin;
        }
        for (const auto& [set, value] : swept) {
            run.sets.push_back(set->key + "=" + value->toml);
            run.setOrigins[set->key] = set->origin;
            const std::string shortKey = set->key.rfind("passes.", 0) == 0 ? set->key.substr(7) : set->key;
            run.name += "--" + sanitise(shortKey + "=" + value->plain);
        }
        plan.runs.push_back(std::move(run));
    };

    if (const toml::node* jobs = root.get("jobs")) {
        const toml::array* list = jobs->as_array();
        if (!list) fail(path, *jobs, "'jobs' must be a list of job files (globs allowed)");
        for (const auto& entry : *list) {
            if (!entry.is_string()) fail(path, entry, "'jobs' entries must be strings (job files or globs)");
            for (const std::string& job : expandGlob(path, entry, planDir, **entry.as_string()))
                addRun(job, where(path, entry), "", {});
        }
    }

    if (const toml::node* sweeps = root.get("sweep")) {
        const toml::array* list = sweeps->as_array();
        if (!list) fail(path, *sweeps, "'sweep' must be an array of tables ([[sweep]])");
        for (const auto& entry : *list) {
            const toml::table* sweep = entry.as_table();
            if (!sweep) fail(path, entry, "each [[sweep]] must be a table");
            checkKeys(path, *sweep, "sweep.", {"job", "reference", "set"});
            const toml::node* job = sweep->get("job");
            if (!job || !job->is_string()) fail(path, job ? *job : entry, "[[sweep]] needs 'job' = a job file or glob");
            std::string reference;
            if (const toml::node* ref = sweep->get("reference")) {
                if (!ref->is_string()) fail(path, *ref, "'sweep.reference' must be an image path");
                const std::string value = **ref->as_string();
                reference = fs::path(value).is_absolute() ? value : (planDir / value).lexically_normal().string();
                std::error_code ec;
                if (!fs::is_regular_file(reference, ec)) fail(path, *ref, "reference '" + value + "' does not exist");
            }
            std::vector<NamedSet> sets;
            if (const toml::node* set = sweep->get("set")) sets = readSetTable(path, *set, "sweep.set", true);
            // Odometer over the value lists: the last key varies fastest.
            std::vector<std::size_t> digits(sets.size(), 0);
            for (const std::string& jobPath : expandGlob(path, *job, planDir, **job->as_string())) {
                std::fill(digits.begin(), digits.end(), 0);
                while (true) {
                    std::vector<std::pair<const NamedSet*, const SetValue*>> swept;
                    for (std::size_t i = 0; i < sets.size(); ++i) swept.emplace_back(&sets[i], &sets[i].values[digits[i]]);
                    addRun(jobPath, where(path, *job), reference, swept);
                    std::size_t i = sets.size();
                    while (i > 0 && ++digits[i - 1] == sets[i - 1].values.size()) digits[--i] = 0;
                    if (i == 0) break;
                }
            }
        }
    }
    if (plan.runs.empty()) throw InputError(path + ": the plan has no runs (add 'jobs' or [[sweep]] entries)");

    std::map<std::string, const BatchRun*> byName;
    for (const BatchRun& run : plan.runs) {
        const auto [it, added] = byName.emplace(run.name, &run);
        if (!added)
            throw InputError(run.origin + ": run '" + run.name + "' is already in the plan (" + it->second->origin +
                             "): its images would overwrite each other");
    }
    return plan;
}

BatchPlan loadBatchPlan(const std::string& path) {
    return parseBatchPlan(readTextInput(path, "batch plan"), path);
}

Job loadBatchJob(const BatchPlan& plan, const BatchRun& run, std::optional<int> threads) {
    JobOverrides overrides;
    overrides.sets = run.sets;
    overrides.outputDirectory = plan.outputDirectory;
    overrides.threads = threads;
    try {
        Job job = loadJob(run.jobPath, overrides);
        job.output.name = run.name;
        job.output.exr = true;
        return job;
    } catch (const InputError& e) {
        throw InputError(runOrigin(run, e.what()) + ": " + e.what());
    }
}

std::vector<Job> validateBatchPlan(const BatchPlan& plan, std::optional<int> threads) {
    std::vector<Job> jobs;
    jobs.reserve(plan.runs.size());
    for (const BatchRun& run : plan.runs) {
        Job job = loadBatchJob(plan, run, threads);
        try {
            const ExecutionPlan built =
                ExecutionPlan::build(job.pipeline, job.params, job.path, installedRegistry().passes, job.bufferFiles);
            // A batch saves no buffers (its runs take no --save, and a job file
            // cannot name one), so no run imports what an earlier run makes:
            // every imported file is there before the batch starts or never
            // is, and is checked here as validate checks it (cheaply, without
            // reading its arrays) instead of failing its run after the scene loads.
            for (const auto& [version, typeAndPath] : built.imports())
                checkBufferFile(typeAndPath.second, typeAndPath.first, version);
        } catch (const InputError& e) {
            throw InputError(runOrigin(run, e.what()) + ": " + e.what());
        }
        jobs.push_back(std::move(job));
    }
    return jobs;
}

}  // namespace fg
