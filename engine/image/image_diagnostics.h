// OpenImageIO reports most failures to read an image through geterror(), but
// some of the libraries beneath its plugins print on stderr themselves: libpng
// writes "libpng error: ..." there before OIIO sees the failure. A bad image
// must still cost the one InputError line, so stderr is captured while an image
// is read and what was printed is folded into that line.
#pragma once

#include <cstdio>
#include <mutex>
#include <string>

namespace fg {

// While alive, the process's stderr (file descriptor 2) goes to a temporary
// file. take() ends the capture and returns what was printed; if it is not
// called, the destructor passes that text on to stderr, so that nothing printed
// meanwhile by a read that succeeds, or by another thread, is lost. Capture is
// best effort: without a temporary file, stderr is left as it is.
class CapturedStderr {
public:
    CapturedStderr();
    ~CapturedStderr();
    CapturedStderr(const CapturedStderr&) = delete;
    CapturedStderr& operator=(const CapturedStderr&) = delete;

    std::string take();

private:
    std::lock_guard<std::mutex> lock_;  // file descriptor 2 is process-wide: one capture at a time
    std::FILE* file_ = nullptr;
    int savedStderr_ = -1;
};

// OIIO's error text and what the image libraries printed, as one line for an
// InputError: lines joined by "; ", blank lines and lines repeated within
// another dropped, the whole bounded in length.
std::string imageReadFailure(const std::string& reportedError, CapturedStderr& printed);

}  // namespace fg
