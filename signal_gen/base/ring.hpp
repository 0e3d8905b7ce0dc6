// A first-in first-out queue of plain values in a ring buffer: blocks go in and come out with
// one copy each (no per-element allocation as in a deque, no compaction as in a vector read
// from a head index). The capacity is a power of two and grows, never shrinks: a stream that
// stays a few blocks ahead keeps a few blocks of memory.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace fringe {

template <class T>
class Ring {
public:
    std::size_t size() const { return tail_ - head_; }
    bool empty() const { return head_ == tail_; }
    void clear() { head_ = tail_ = 0; }
    // Appends n values.
    void push(const T* src, std::size_t n) {
        reserve(size() + n);
        const std::size_t cap = buf_.size(), at = tail_ & (cap - 1), first = std::min(n, cap - at);
        std::copy_n(src, first, buf_.data() + at);
        std::copy_n(src + first, n - first, buf_.data());
        tail_ += n;
    }
    // n copies of one value.
    void push_fill(const T& v, std::size_t n) {
        reserve(size() + n);
        const std::size_t cap = buf_.size(), at = tail_ & (cap - 1), first = std::min(n, cap - at);
        std::fill_n(buf_.data() + at, first, v);
        std::fill_n(buf_.data(), n - first, v);
        tail_ += n;
    }
    // Takes the n oldest values (n <= size()) into dst.
    void pop(T* dst, std::size_t n) {
        const std::size_t cap = buf_.size(), at = head_ & (cap - 1), first = std::min(n, cap - at);
        std::copy_n(buf_.data() + at, first, dst);
        std::copy_n(buf_.data(), n - first, dst + first);
        head_ += n;
    }

private:
    void reserve(std::size_t want) {
        if (want <= buf_.size()) return;
        std::size_t cap = 1024;
        while (cap < want) cap *= 2;
        std::vector<T> grown(cap);
        const std::size_t n = size();
        pop(grown.data(), n);
        buf_.swap(grown);
        head_ = 0;
        tail_ = n;
    }
    std::vector<T> buf_;
    std::size_t head_ = 0, tail_ = 0;  // values taken and given since the last growth (indices mod capacity)
};

}  // namespace fringe
