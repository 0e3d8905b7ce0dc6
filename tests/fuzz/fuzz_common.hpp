// Shared by the fuzz targets (README "Fuzzing"): a scratch folder for inputs that must be
// files, and one way to fail. Each target is built twice: with libFuzzer (FRINGE_FUZZ, clang)
// and with replay_main.cpp, which runs the kept regression inputs under ctest.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <typeinfo>

namespace fringe::fuzz {

// A private folder under TMPDIR, removed at exit. The name is never freed: the exit handler,
// registered while it is being initialised, runs after a static string's destructor would.
inline const std::string& scratch_dir() {
    static const std::string* const dir = new std::string([] {
        std::string tmpl = (std::filesystem::temp_directory_path() / "fringe-fuzz-XXXXXX").string();
        if (!mkdtemp(tmpl.data())) {
            std::perror("mkdtemp");
            std::abort();
        }
        std::atexit([] {
            std::error_code ec;
            std::filesystem::remove_all(scratch_dir(), ec);
        });
        return tmpl;
    }());
    return *dir;
}

inline void write_file(const std::string& path, const char* data, std::size_t size) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    f.write(data, static_cast<std::streamsize>(size));
    if (!f) {
        std::fprintf(stderr, "fuzz: cannot write %s\n", path.c_str());
        std::abort();
    }
}

// A broken promise: libFuzzer keeps the input as a crash, the replay test fails.
[[noreturn]] inline void fail(const std::string& what) {
    std::fprintf(stderr, "fuzz: %s\n", what.c_str());
    std::abort();
}

[[noreturn]] inline void unexpected(const std::exception& e) {
    fail(std::string("unexpected exception ") + typeid(e).name() + ": " + e.what());
}

}  // namespace fringe::fuzz
