// Writing output files so that a failed run leaves nothing under a final name.
//
// Every file is written to a temporary name in its destination directory with
// write(2), fsync(2) and close(2), each result checked: a full disk or a failed
// device surfaces here, as an InputError naming the final path, rather than as
// a truncated file that the next reader mistakes for a result. The image
// encoders (OpenEXR, libpng) write into memory, and their bytes go through
// the same checked path.
//
// A run's outputs are committed as a set (OutputCommit): each is written to
// its temporary, and only when all are written are they renamed onto their
// final names.
#pragma once

#include "engine/core/interrupt.h"

#include <filesystem>
#include <functional>
#include <mutex>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace fg {

// A fresh name next to `path`: ".<stem>.tmp-<pid>-<n><ext>" (the extension
// stays last so that format detection by name still works).
std::string temporaryPathFor(const std::string& path);

// Creates (or truncates) `temporaryPath` and writes what `fill` streams into
// it, checking every write, the fsync and the close. On failure removes the
// temporary and throws InputError "<finalPath>: cannot write: <reason>".
void writeFileChecked(const std::string& finalPath, const std::string& temporaryPath,
                      const std::function<void(std::ostream&)>& fill);
void writeFileChecked(const std::string& finalPath, const std::string& temporaryPath, std::string_view bytes);

// Renames `from` onto `to`; throws InputError naming `to`.
void atomicRename(const std::string& from, const std::string& to);

// Writes to temporaryPathFor(path) through `writer`, then renames onto `path`;
// removes the temporary on any failure and rethrows.
template <class Writer>
void writeAtomically(const std::string& path, Writer&& writer) {
    const std::string temporary = temporaryPathFor(path);
    registerTemporaryFile(temporary);
    try {
        writer(temporary);
        atomicRename(temporary, path);
    } catch (...) {
        std::error_code ignored;
        std::filesystem::remove(temporary, ignored);
        unregisterCleanupPath(temporary);
        throw;
    }
    unregisterCleanupPath(temporary);
}

// The outputs of one run, all or none. stage() hands out the temporary to
// write a final path through; commit() renames every staged temporary onto
// its final name. Destroyed without a successful commit, it removes every
// temporary and every directory it created, so a failed run leaves the file
// system as it found it (except for files a midway rename failure replaced,
// see commit()). stage() may be called from several threads.
class OutputCommit {
public:
    OutputCommit() = default;
    OutputCommit(const OutputCommit&) = delete;
    OutputCommit& operator=(const OutputCommit&) = delete;
    ~OutputCommit();

    // Creates `directory` and any missing parents, remembering which it made.
    // Throws InputError if it cannot.
    void createDirectories(const std::string& directory);
    std::string stage(const std::string& finalPath);
    // Throws InputError if a final name is taken by a directory (before any
    // rename) or a rename fails; then the outputs already renamed are removed
    // again, best effort: a file they replaced is not brought back.
    void commit();

private:
    struct Staged {
        std::string finalPath;
        std::string temporaryPath;
    };
    void rollBack(std::size_t renamedCount) noexcept;

    std::mutex mutex_;
    std::vector<Staged> staged_;
    std::vector<std::filesystem::path> createdDirectories_;  // parents first
    bool committed_ = false;
};

}  // namespace fg
