#include "server/engine/frame_source.hpp"

#include "server/analysis/align.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <limits>
#include <optional>

#include <spdlog/spdlog.h>

namespace fringe {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Device teardown from a destructor runs while a failure may be unwinding (an instrument lost
// mid-run): best effort, logged, never thrown (a throw there ends the process).
template <class F>
void teardown(const char* what, F&& f) noexcept {
    try {
        f();
    } catch (const std::exception& e) {
        try { spdlog::warn("{} after the run failed: {}", what, e.what()); } catch (...) {}
    } catch (...) {
        try { spdlog::warn("{} after the run failed: unknown exception", what); } catch (...) {}
    }
}

class StepSource final : public FrameSource {
public:
    StepSource(const Scenario& sc, dev::StepPort& d, bool dut)
        : sc_(sc), dev_(d), gen_(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s), dut_(dut) {}
    SourceStatus next(std::size_t max, Frames& out) override {
        // Static steps are slow (a settle each): small blocks keep progress and cancel prompt.
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>({max, 16, sc_.samples() - k_}));
        b_.resize(n, sc_.encoder.index.enabled);
        gen_.generate(k_, b_);
        out.resize(n, dut_);
        for (std::size_t i = 0; i < n; ++i) {
            dev::StepResult r;
            // A step that fails ends the block there: the steps measured before it are delivered
            // (scored, recorded) with the error; a cancel delivers them too and the run ends as aborted.
            try {
                r = dev_.measure(b_.sin_v[i], b_.cos_v[i], -1.0, 0);  // the device's settle and averaging
            } catch (const dev::Cancelled&) {
                out.resize(i, dut_);
                k_ += i;
                return {};
            } catch (const std::exception& e) {
                out.resize(i, dut_);
                k_ += i;
                return {false, false, e.what()};
            }
            out.sin_v[i] = r.sin_v;
            out.cos_v[i] = r.cos_v;
            if (dut_) out.dut_theta_rad[i] = r.dut_theta_rad ? *r.dut_theta_rad : kNaN;
            out.t_s[i] = b_.t_s[i];
            out.theta_true_rad[i] = b_.theta_rad[i];
            out.omega_true_rad_s[i] = b_.omega_rad_s[i];
            out.truth_known[i] = 1;
        }
        k_ += n;
        return {};
    }

private:
    const Scenario& sc_;
    dev::StepPort& dev_;
    Generator gen_;
    Block b_;
    std::uint64_t k_ = 0;
    bool dut_;
};

class StreamSource final : public FrameSource {
public:
    StreamSource(const Scenario& sc, dev::StreamPort& d, const dev::DeviceInfo& info, std::size_t block)
        : sc_(sc), dev_(d), gen_(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s),
          ahead_gen_(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s), block_(block), total_(sc.samples()),
          ahead_(static_cast<std::uint64_t>(std::max(1, info.output_ahead_blocks))) {
        // The first latency_samples input frames predate the signal and are not scored.
        if (info.latency_samples > 0) {
            Block lat;
            lat.resize(static_cast<std::size_t>(info.latency_samples), false);
            for (int k = 0; k < info.latency_samples; ++k) {
                lat.t_s[static_cast<std::size_t>(k)] = sc.t0_s + k / sc.sample_rate_hz;
                lat.theta_rad[static_cast<std::size_t>(k)] = lat.omega_rad_s[static_cast<std::size_t>(k)] = 0;
            }
            pending_.push(lat, 0);
        }
        dev_.start(sc.sample_rate_hz);
        started_ = true;
    }
    ~StreamSource() override { teardown("stopping the device's streams", [&] { stop(); }); }
    void stop() override {
        if (started_) {
            started_ = false;
            dev_.stop();
        }
    }
    // Call c of next() writes block c + A - 1 once the first call has written blocks 0..A-1 (A
    // = the device's output_ahead_blocks, every call reading one): this generates block c + A,
    // for call c + 1, with a generator of its own. The generator's output depends only on the
    // sample index.
    void generate_ahead() override {
        const std::uint64_t c = ahead_calls_++;
        const std::size_t slot = static_cast<std::size_t>(c % 2);
        const std::uint64_t first = (c + ahead_) * block_;
        pre_first_[slot] = kNone;
        if (first >= total_) return;
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(block_, total_ - first));
        pre_[slot].resize(n, sc_.encoder.index.enabled);
        ahead_gen_.generate(first, pre_[slot]);
        pre_first_[slot] = first;
    }
    SourceStatus next(std::size_t max, Frames& out) override {
        const std::uint64_t call = next_calls_++;
        // What generate_ahead() made beside the call before (another slot than the one it fills now).
        const std::size_t ready = static_cast<std::size_t>((call + 1) % 2);
        const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(max, total_ - k_in_));
        // Output runs up to A blocks ahead of input (four for a real-time board, which must
        // never run dry while the host reads). Truth is queued as it is written.
        while (k_out_ < std::min<std::uint64_t>(total_, k_in_ + ahead_ * block_)) {
            const std::size_t nw = static_cast<std::size_t>(std::min<std::uint64_t>(block_, total_ - k_out_));
            Block* b = &b_;
            if (call > 0 && pre_first_[ready] == k_out_ && pre_[ready].size() == nw) {
                b = &pre_[ready];
                pre_first_[ready] = kNone;  // its buffers go to the truth queue below
            } else {
                b_.resize(nw, sc_.encoder.index.enabled);
                gen_.generate(k_out_, b_);
            }
            const auto w = dev_.write(b->sin_v, b->cos_v);
            if (w.status != dev::StreamStatus::Ok)
                return {false, false, std::string("output ") + dev::to_string(w.status) + " at sample " + std::to_string(k_out_ + w.frames) + ": " + w.message};
            pending_.push(*b, 1);
            k_out_ += nw;
            if (k_out_ == total_) dev_.end_of_output();
        }
        out.resize(want, false);
        std::size_t got = 0;
        while (got < want) {
            const auto r = dev_.read(std::span(out.sin_v).subspan(got), std::span(out.cos_v).subspan(got), 1000);
            if (r.status == dev::StreamStatus::Overflow || r.dropped) {
                out.resize(got, false);
                fill_truth(out);
                return {false, false, "sample loss: " + std::to_string(r.dropped) + " input samples dropped before input sample " +
                                          std::to_string(r.first_index) + " (" + r.message + ")"};
            }
            if (r.status != dev::StreamStatus::Ok || r.frames == 0) {
                const std::string what = r.status != dev::StreamStatus::Ok ? std::string("input ") + dev::to_string(r.status) + " at input sample " + std::to_string(k_in_ + got) + ": " + r.message
                                                                             : "input underrun: the device returned no samples at input sample " + std::to_string(k_in_ + got);
                out.resize(got, false);
                fill_truth(out);
                return {false, false, what};
            }
            got += r.frames;
        }
        fill_truth(out);
        return {};
    }

private:
    // The truth of the frames written and not yet read, in order: the written blocks themselves,
    // kept until their frames are read (each value copied once, into the frames), their buffers
    // then recycled for the blocks generated next.
    struct TruthFifo {
        struct Piece {
            Block b;
            std::size_t from = 0;  // frames of b already read
            std::uint8_t known = 1;
        };
        std::deque<Piece> q;
        std::vector<Block> spare;
        // Takes b's buffers (b gets recycled ones, to be resized and filled by its next user).
        void push(Block& b, std::uint8_t known) {
            if (!b.size()) return;
            Piece p;
            if (!spare.empty()) {
                p.b = std::move(spare.back());
                spare.pop_back();
            }
            std::swap(p.b, b);
            p.known = known;
            q.push_back(std::move(p));
        }
        void pop(std::size_t n, Frames& out) {
            std::size_t got = 0;
            while (got < n) {
                Piece& p = q.front();
                const std::size_t take = std::min(n - got, p.b.size() - p.from);
                std::copy_n(p.b.t_s.data() + p.from, take, out.t_s.data() + got);
                std::copy_n(p.b.theta_rad.data() + p.from, take, out.theta_true_rad.data() + got);
                std::copy_n(p.b.omega_rad_s.data() + p.from, take, out.omega_true_rad_s.data() + got);
                std::fill_n(out.truth_known.data() + got, take, p.known);
                p.from += take;
                got += take;
                if (p.from == p.b.size()) {
                    spare.push_back(std::move(p.b));
                    q.pop_front();
                }
            }
        }
    };
    void fill_truth(Frames& out) {
        pending_.pop(out.size(), out);
        k_in_ += out.size();
    }
    static constexpr std::uint64_t kNone = ~std::uint64_t{0};
    const Scenario& sc_;
    dev::StreamPort& dev_;
    Generator gen_, ahead_gen_;  // next()'s own, and generate_ahead()'s
    Block b_;
    Block pre_[2];  // generate_ahead()'s blocks, by the parity of its call, and their first samples
    std::uint64_t pre_first_[2] = {kNone, kNone};
    std::uint64_t next_calls_ = 0, ahead_calls_ = 0;
    std::size_t block_;
    std::uint64_t total_, ahead_, k_out_ = 0, k_in_ = 0;
    TruthFifo pending_;
    bool started_ = false;
};

class ReplaySource final : public FrameSource {
public:
    ReplaySource(const Scenario& sc, dev::ReplayPort& d, bool dut) : sc_(sc), dev_(d), total_(sc.samples()), dut_(dut) {
        dev_.start(sc.sample_rate_hz);
    }
    SourceStatus next(std::size_t max, Frames& out) override {
        const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(max, total_ - k_));
        out.resize(want, dut_);
        std::size_t got = 0;
        while (got < want) {
            const auto r = dev_.read(std::span(out.sin_v).subspan(got), std::span(out.cos_v).subspan(got), 1000);
            if (r.status != dev::StreamStatus::Ok || r.dropped) {
                out.resize(got, dut_);
                k_ += got;
                return {false, false, std::string("input ") + dev::to_string(r.status) + " at input sample " + std::to_string(k_) + ": " + r.message};
            }
            if (r.frames == 0) {  // the capture's end
                out.resize(got, dut_);
                k_ += got;
                return {true, true, ""};
            }
            th_.resize(r.frames);
            om_.resize(r.frames);
            const bool has = dev_.last_truth(th_, om_);
            if (dut_ && !dev_.last_dut(std::span(out.dut_theta_rad).subspan(got, r.frames)))
                std::fill_n(out.dut_theta_rad.begin() + static_cast<std::ptrdiff_t>(got), r.frames, kNaN);
            for (std::size_t i = 0; i < r.frames; ++i) {
                out.t_s[got + i] = sc_.t0_s + static_cast<double>(k_ + got + i) / sc_.sample_rate_hz;
                out.theta_true_rad[got + i] = has ? th_[i] : kNaN;
                out.omega_true_rad_s[got + i] = has ? om_[i] : kNaN;
                out.truth_known[got + i] = has;
            }
            got += r.frames;
        }
        k_ += got;
        return {};
    }

private:
    const Scenario& sc_;
    dev::ReplayPort& dev_;
    std::uint64_t total_, k_ = 0;
    std::vector<double> th_, om_;
    bool dut_;
};

// Instrument mode: synthesise the whole run, play it from the generator's memory, record it
// on the digitizer's clock, align (delay, clock ratio, gain, offset) and deliver the record's
// frames from the output's first sample on, each with the truth at the generator time it shows.
class InstrumentSource final : public FrameSource {
public:
    InstrumentSource(const Scenario& sc, dev::PlayPort& out, dev::RecordPort& in)
        : sc_(sc), out_(out), in_(in), max_play_(out.memory_samples()) {}
    ~InstrumentSource() override { teardown("stopping the generator's output", [&] { stop(); }); }
    void stop() override {
        if (playing_) {
            playing_ = false;
            out_.stop_output();
        }
    }
    nlohmann::json alignment() const override { return info_; }
    SourceStatus next(std::size_t max, Frames& out) override {
        if (!prepared_) {
            prepared_ = true;
            const SourceStatus st = prepare();
            if (!st.ok) return st;
        }
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(max, frames_ - k_));
        out.resize(n, false);
        if (n == 0) return {true, true, ""};
        tb_.resize(n, false);
        truth_->generate(m0_ + k_, tb_);
        for (std::size_t i = 0; i < n; ++i) {
            const std::size_t m = static_cast<std::size_t>(m0_ + k_) + i;
            out.sin_v[i] = rs_[m];
            out.cos_v[i] = rc_[m];
            out.t_s[i] = tb_.t_s[i];
            out.theta_true_rad[i] = tb_.theta_rad[i];
            out.omega_true_rad_s[i] = tb_.omega_rad_s[i];
            // After a single playback's last sample the output is idle: no truth there.
            out.truth_known[i] = tb_.t_s[i] - sc_.t0_s <= t_end_s_;
        }
        k_ += n;
        return {};
    }

private:
    static std::string fmt(double v) {
        char b[32];
        std::snprintf(b, sizeof b, "%.6g", v);
        return b;
    }
    SourceStatus fail(const std::string& why) { return {false, false, why}; }

    SourceStatus prepare() {
        const std::uint64_t N = sc_.samples();
        const double fs = sc_.sample_rate_hz;
        constexpr std::uint64_t kMaxSamples = 1ull << 25;  // played and recorded pairs are held in memory
        if (N > kMaxSamples)
            return fail("instrument mode holds the whole run in memory: " + std::to_string(N) + " samples exceed " + std::to_string(kMaxSamples) +
                        " (shorten duration_s or lower sample_rate_hz)");
        // What the generator plays: the whole run once, or (constant speed) a whole number of
        // periods repeated when the run does not fit its memory.
        // A single playback runs from kLead samples before the run's first sample to a tail after
        // its last, so the scored frames never see the output's start or end (where a
        // band-limited output rings); the tail also covers a generator clock up to 1000 ppm fast.
        constexpr std::uint64_t kLead = 64;
        const std::uint64_t tail = 64 + N / 1000;
        bool cyclic = false;
        double play_fs = fs;
        std::uint64_t L = kLead + N + tail, periods = 0;
        bool segmented = false;
        std::uint64_t segments = 0, segment_samples = 0;
        if (max_play_ > 0 && L > max_play_) {
            const auto& m = sc_.motion;
            const std::string limit = "the run needs " + std::to_string(L) + " samples per channel (" + std::to_string(N) + " and " +
                                      std::to_string(kLead + tail) + " around them) but the generator holds " +
                                      std::to_string(max_play_) + " (max_play_samples)";
            dev::SequencePort* seq = out_.sequencer();
            // Why it cannot play as a repeated block ("" when it can).
            std::string no_repeat;
            const bool per_rev = sc_.encoder.geometry_varies();
            const double f_hz = std::fabs(m.velocity_rad_s) / kTwoPi * (per_rev ? 1.0 : static_cast<double>(sc_.encoder.lines_per_rev));
            if (m.kind != MotionKind::Constant || m.velocity_rad_s == 0)
                no_repeat = "only a constant-speed motion can play as a repeated block";
            else if (sc_.encoder.noise.drift_amplitude != 0)
                no_repeat = "the encoder's gain drift (noise.drift_amplitude) does not repeat, so the run cannot play as a repeated block";
            else {
                // The block repeats seamlessly when it holds whole electrical cycles, or whole
                // revolutions when the encoder has per-revolution effects (eccentricity, gap).
                periods = static_cast<std::uint64_t>(std::floor(static_cast<double>(max_play_) * f_hz / fs));
                if (periods < 1)
                    no_repeat = "one " + std::string(per_rev ? "revolution" : "electrical cycle") + " (" + fmt(fs / f_hz) + " samples) does not fit";
            }
            if (no_repeat.empty()) {
                L = static_cast<std::uint64_t>(std::floor(static_cast<double>(periods) * fs / f_hz));
                play_fs = static_cast<double>(L) * f_hz / static_cast<double>(periods);  // exactly `periods` periods in L samples
                cyclic = true;
            } else if (!seq) {
                return fail(limit + ": " + no_repeat + ", and the generator cannot play it in segments (" + out_.sequence_refusal() +
                            "); shorten duration_s or lower sample_rate_hz");
            } else {
                // Segmented: as few segments as the memory allows, of equal length (the last
                // one shorter by less than the count), played back to back from one start.
                const dev::SequenceLimits lim = seq->sequence_limits();
                const std::uint64_t max_seg = std::min<std::uint64_t>(lim.max_segment_samples, max_play_);
                segments = (L + max_seg - 1) / max_seg;
                segment_samples = (L + segments - 1) / segments;
                const std::uint64_t last = L - (segments - 1) * segment_samples;
                if (segments > lim.max_segments)
                    return fail(limit + ": " + no_repeat + "; in segments of at most " + std::to_string(max_seg) + " samples it needs " + std::to_string(segments) +
                                " segments, more than the generator's " + std::to_string(lim.max_segments) +
                                " (max_segments); shorten duration_s or lower sample_rate_hz");
                if (segment_samples < lim.min_segment_samples || last < lim.min_segment_samples)
                    return fail(limit + ": " + no_repeat + "; its segments of " + std::to_string(segment_samples) + " samples (the last " + std::to_string(last) +
                                ") are shorter than the generator's minimum of " + std::to_string(lim.min_segment_samples));
                segmented = true;
            }
        }
        {
            Generator g(sc_.encoder, sc_.motion, play_fs, sc_.seed, sc_.t0_s - static_cast<double>(kLead) / play_fs);
            Block b;
            ps_.resize(L);
            pc_.resize(L);
            for (std::uint64_t k = 0; k < L; k += 65536) {
                const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(65536, L - k));
                b.resize(n, sc_.encoder.index.enabled);
                g.generate(k, b);
                std::copy(b.sin_v.begin(), b.sin_v.end(), ps_.begin() + static_cast<std::ptrdiff_t>(k));
                std::copy(b.cos_v.begin(), b.cos_v.end(), pc_.begin() + static_cast<std::ptrdiff_t>(k));
            }
        }
        // The record runs on past the run by a margin for the delay (the output starts after the record).
        const std::uint64_t pad = std::max<std::uint64_t>(4096, N / 20);
        const std::uint64_t M = N + pad;
        info_ = {{"playback", {{"mode", cyclic ? "cyclic" : segmented ? "segmented" : "once"}, {"samples", L}, {"lead_samples", kLead}, {"rate_hz", play_fs}, {"record_samples", M}, {"record_rate_hz", fs}}}};
        if (cyclic) info_["playback"]["periods"] = periods;
        if (segmented) {
            info_["playback"]["segments"] = segments;
            info_["playback"]["segment_samples"] = segment_samples;
        }
        // An instrument lost here (gone, frozen) ends the run as an error with this reason and
        // the playback above in its report; the output is switched off as far as it still can be.
        dev::StreamResult r;
        try {
            if (segmented) out_.sequencer()->play_segments(ps_, pc_, static_cast<std::size_t>(segment_samples), play_fs);
            else out_.play(ps_, pc_, play_fs, cyclic);
            playing_ = true;
            rs_.resize(M);
            rc_.resize(M);
            r = in_.record(rs_, rc_, fs, static_cast<double>(M) / fs * 1.5 + 10.0);
        } catch (const std::exception& e) {
            const std::string why = std::string(playing_ ? "record: " : "play: ") + e.what();
            teardown("stopping the generator's output", [&] { stop(); });
            return fail(why);
        }
        if (r.status != dev::StreamStatus::Ok || r.dropped) {
            teardown("stopping the generator's output", [&] { stop(); });
            return fail(std::string("record ") + dev::to_string(r.status) + ": " + r.message);
        }
        try {
            stop();
        } catch (const std::exception& e) {
            return fail(std::string("the record is complete but the generator's output could not be stopped: ") + e.what());
        }
        if (r.frames < M) return fail("record returned " + std::to_string(r.frames) + " of " + std::to_string(M) + " samples");

        AlignInput ai;
        ai.played_sin_v = ps_;
        ai.played_cos_v = pc_;
        ai.play_rate_hz = play_fs;
        ai.cyclic = cyclic;
        ai.recorded_sin_v = rs_;
        ai.recorded_cos_v = rc_;
        ai.record_rate_hz = fs;
        const AlignResult a = align(ai);
        nlohmann::json aj = a;
        aj["playback"] = info_["playback"];
        info_ = aj;
        if (!a.ok) return fail("alignment not confident: " + a.error);
        if (segmented) {
            // One alignment spans every segment; a join that dropped or repeated a sample
            // shifts the segments after it, which the fit can absorb as a clock offset (four
            // one-sample slips in 20000 samples look like 200 ppm). Each segment's own time
            // shift against the fit must agree with the others'.
            const std::vector<double> off = segment_offsets_samples(a, L, segment_samples, play_fs);
            std::vector<double> sorted;  // segments too short to measure (NaN) are left out
            for (double v : off)
                if (std::isfinite(v)) sorted.push_back(v);
            std::sort(sorted.begin(), sorted.end());
            const double med = sorted.empty() ? 0.0 : sorted[sorted.size() / 2];
            info_["playback"]["segment_offsets_samples"] = off;
            for (std::size_t k = 0; k < off.size(); ++k)
                if (std::isfinite(off[k]) && std::fabs(off[k] - med) > kMaxSegmentOffsetSamples)
                    return fail("segment joins: segment " + std::to_string(k) + " of " + std::to_string(off.size()) + " plays " + fmt(off[k] - med) +
                                " samples off the others (at most " + fmt(kMaxSegmentOffsetSamples) +
                                "): a sample dropped or repeated where the generator joins segments");
        }

        // Frames from the first record sample at or after the run's first sample (generator time
        // kLead / play_fs: played sample n is at t0 + (n - kLead) / play_fs).
        const double kappa = a.clock_offset_ppm * 1e-6;
        const double lead_s = static_cast<double>(kLead) / play_fs;
        const double first = std::ceil((lead_s - a.tau0_s) * fs / (1 + kappa) - 1e-9);
        if (first < 0)  // the record started after the run's first sample was played
            return fail("the record started " + fmt(-a.delay_s) + " s after the output and misses the run's first " + fmt(-first) +
                        " samples: start the digitizer before the generator (arm it first, or give it a pretrigger)");
        m0_ = static_cast<std::uint64_t>(first);
        if (m0_ + N > M)
            return fail("the output appeared " + fmt(a.delay_s) + " s after the record started: the record (" + std::to_string(M) +
                        " samples) ends before the run's " + std::to_string(N) + " samples that follow");
        frames_ = N;
        t_end_s_ = cyclic ? std::numeric_limits<double>::infinity() : static_cast<double>(L - 1 - kLead) / play_fs;
        info_["first_frame"] = m0_;
        // Truth at the record's sample times on the generator's clock: a generator whose sample m
        // lies at t0 + tau(m). Noise does not touch the truth: left out for speed.
        EncoderProfile enc = sc_.encoder;
        enc.noise.sigma_add_v = enc.noise.sigma_gain = enc.noise.drift_amplitude = 0;
        truth_.emplace(enc, sc_.motion, fs / (1 + kappa), sc_.seed, sc_.t0_s + a.tau0_s - lead_s);
        // Played and recorded samples before the first frame are no longer needed; the rest stays.
        std::vector<double>().swap(ps_);
        std::vector<double>().swap(pc_);
        return {};
    }

    // How far (generator samples) a segment's own time shift may lie from the others'.
    static constexpr double kMaxSegmentOffsetSamples = 0.05;
    // Each segment's time shift against the alignment (generator samples; + : the record shows
    // the segment later than the fit says), by one Gauss-Newton step on the fitted model over
    // up to 4096 record samples inside the segment (32 samples clear of its joins).
    std::vector<double> segment_offsets_samples(const AlignResult& a, std::uint64_t L, std::uint64_t seg, double play_fs) const {
        const std::uint64_t n_seg = (L + seg - 1) / seg;
        std::vector<double> num(n_seg, 0.0), den(n_seg, 0.0);
        const double h_s = 0.05 / play_fs;
        const std::size_t M = rs_.size();
        const double step = std::max(1.0, static_cast<double>(std::min<std::uint64_t>(seg, M)) / 4096.0);
        for (double mf = 0; mf < static_cast<double>(M); mf += step) {
            const auto m = static_cast<std::size_t>(mf);
            const double t = a.output_time_s(static_cast<double>(m));
            const double u = t * play_fs;  // generator sample position
            if (u < 0 || u >= static_cast<double>(L)) continue;
            const auto k = static_cast<std::uint64_t>(u) / seg;
            const double in_seg = u - static_cast<double>(k * seg);
            if (in_seg < 32 || in_seg > static_cast<double>(std::min(seg, L - k * seg)) - 32) continue;
            for (int ch = 0; ch < 2; ++ch) {
                const std::span<const double> p = ch == 0 ? std::span<const double>(ps_) : std::span<const double>(pc_);
                const AlignChannel& c = ch == 0 ? a.sin : a.cos;
                const double model = c.gain * played_value(p, play_fs, false, t) + c.offset_v;
                const double d = c.gain * (played_value(p, play_fs, false, t + h_s) - played_value(p, play_fs, false, t - h_s)) / (2 * h_s);
                const double r = (ch == 0 ? rs_[m] : rc_[m]) - model;
                // recorded(t) = model(t - dt): r = -d * dt
                num[k] -= r * d;
                den[k] += d * d;
            }
        }
        std::vector<double> off(n_seg, 0.0);
        for (std::uint64_t k = 0; k < n_seg; ++k) off[k] = den[k] > 0 ? num[k] / den[k] * play_fs : std::numeric_limits<double>::quiet_NaN();
        return off;
    }

    const Scenario& sc_;
    dev::PlayPort& out_;
    dev::RecordPort& in_;
    std::size_t max_play_;
    bool prepared_ = false, playing_ = false;
    std::vector<double> ps_, pc_, rs_, rc_;
    std::uint64_t m0_ = 0, frames_ = 0, k_ = 0;
    double t_end_s_ = 0;
    std::optional<Generator> truth_;
    Block tb_;
    nlohmann::json info_;
};

// Bench checks on what a hardware input delivers (docs/bench.md "Clipping and frozen inputs"):
// faults of the bench, not of the DUT, end the run as ERROR naming the device and the evidence.
//  - clipping at known rails: more than kClipShare of a channel's samples at or beyond the ADC's
//    full scale (within one step of +-adc_range_v), once 100 samples are in and at the end;
//  - clipping at unknown rails (a board whose range is not what its profile says): at the end,
//    more than kPlateauShare of a channel's samples on its largest or smallest value (within one
//    step, or 1e-9 of the span for an ideal converter), when the truth spanned a full
//    electrical cycle (a sinusoid spends about sqrt(2 step / A) / pi of a cycle within one step
//    of its peak: 0.3 % for 16 bits, 4.5 % for 8);
//  - a frozen input: kFrozenRun consecutive samples with both channels exactly equal while the
//    truth moved more than 1 rad, or a block of 16 or more samples exactly equal to the block
//    before it while the truth did not repeat (a board returning old data).
class BenchChecks final : public FrameSource {
public:
    BenchChecks(std::unique_ptr<FrameSource> inner, const dev::DeviceInfo& in, std::uint64_t total)
        : inner_(std::move(inner)), device_(in.uri), total_(total) {
        const auto& c = in.converter;
        rail_v_ = c.adc_range_v > 0 ? c.adc_range_v : 0.0;
        step_v_ = c.adc_q_v();
    }
    void generate_ahead() override { inner_->generate_ahead(); }
    void stop() override { inner_->stop(); }
    nlohmann::json alignment() const override { return inner_->alignment(); }
    SourceStatus next(std::size_t max, Frames& out) override {
        SourceStatus st = inner_->next(max, out);
        const std::string why = check(out);
        if (!why.empty() && st.ok) return {false, false, why};
        return st;
    }

private:
    static constexpr double kClipShare = 0.01, kPlateauShare = 0.05;
    static constexpr std::size_t kFrozenRun = 32;
    struct Chan {
        std::uint64_t at_rail = 0;
        double hi = -std::numeric_limits<double>::infinity(), lo = std::numeric_limits<double>::infinity();
        std::uint64_t at_hi = 0, at_lo = 0;
    };
    static std::string fmt(double v) {
        char b[32];
        std::snprintf(b, sizeof b, "%.4g", v);
        return b;
    }
    void plateau(Chan& c, double v, double tol) {
        if (v > c.hi + tol) { c.hi = v; c.at_hi = 1; }
        else if (v >= c.hi - tol) ++c.at_hi;
        if (v < c.lo - tol) { c.lo = v; c.at_lo = 1; }
        else if (v <= c.lo + tol) ++c.at_lo;
    }
    std::string check(const Frames& f) {
        const std::size_t n = f.size();
        const char* names[2] = {"sin", "cos"};
        const std::vector<double>* ch[2] = {&f.sin_v, &f.cos_v};
        for (std::size_t i = 0; i < n; ++i) {
            const double s = f.sin_v[i], c = f.cos_v[i];
            for (int k = 0; k < 2; ++k) {
                const double v = (*ch[k])[i];
                if (!std::isfinite(v)) continue;
                if (rail_v_ > 0 && std::fabs(v) >= rail_v_ - std::max(step_v_, 1e-9 * rail_v_)) ++chan_[k].at_rail;
                plateau(chan_[k], v, step_v_ > 0 ? step_v_ / 2 : 0.0);
            }
            // Runs of exactly equal pairs, and how far the truth moved across them. An exact
            // (0, 0) is what a step-mode board without ADC registers returns: not a reading.
            if (s == 0 && c == 0) {
                run_ = 0;
            } else if (seen_ > 0 && s == last_s_ && c == last_c_) {
                ++run_;
            } else {
                run_ = 1;
                run_start_ = seen_;
                run_theta0_ = f.truth_known[i] ? f.theta_true_rad[i] : kNaN;
            }
            if (f.truth_known[i]) {
                th_min_ = std::min(th_min_, f.theta_true_rad[i]);
                th_max_ = std::max(th_max_, f.theta_true_rad[i]);
                if (run_ >= kFrozenRun && std::fabs(f.theta_true_rad[i] - run_theta0_) > 1.0)
                    return "bench: the input of " + device_ + " is frozen: " + std::to_string(run_) + " consecutive samples from input sample " +
                           std::to_string(run_start_) + " read exactly sin " + fmt(s) + " V, cos " + fmt(c) + " V while the signal moved " +
                           fmt(std::fabs(f.theta_true_rad[i] - run_theta0_)) + " rad (the board repeats old data, or the drive never reaches its input: wiring, or the drive registers' address, type or word order; not a fault of the DUT)";
            }
            last_s_ = s;
            last_c_ = c;
            ++seen_;
        }
        // A block that repeats the one before it exactly while the truth did not repeat.
        if (n >= 16 && prev_.size() == n && prev_truth_known_ && f.truth_known[0] &&
            std::fabs(std::remainder(f.theta_true_rad[0] - prev_theta0_, kTwoPi)) > 0.01 &&
            std::equal(f.sin_v.begin(), f.sin_v.end(), prev_.begin()) && std::equal(f.cos_v.begin(), f.cos_v.end(), prev_c_.begin()))
            return "bench: the input of " + device_ + " is frozen: the " + std::to_string(n) + " samples from input sample " + std::to_string(seen_ - n) +
                   " repeat the block before them exactly while the signal moved on (the board returns old data; not a fault of the DUT)";
        prev_.assign(f.sin_v.begin(), f.sin_v.end());
        prev_c_.assign(f.cos_v.begin(), f.cos_v.end());
        prev_truth_known_ = n > 0 && f.truth_known[0];
        prev_theta0_ = n > 0 ? f.theta_true_rad[0] : 0.0;
        const bool end = seen_ >= total_;
        if (rail_v_ > 0 && (seen_ >= 100 || end) && seen_ > 0)
            for (int k = 0; k < 2; ++k)
                if (static_cast<double>(chan_[k].at_rail) > kClipShare * static_cast<double>(seen_))
                    return "bench: clipping at the input of " + device_ + ": " + fmt(100.0 * static_cast<double>(chan_[k].at_rail) / static_cast<double>(seen_)) + " % of " +
                           names[k] + " samples (" + std::to_string(chan_[k].at_rail) + " of " + std::to_string(seen_) + ") at or beyond its ADC's rails +-" + fmt(rail_v_) +
                           " V (more than " + fmt(100 * kClipShare) + " % is clipping, not a fault of the DUT): lower the signal's amplitude or raise the input range";
        if (end && th_max_ - th_min_ >= kTwoPi)
            for (int k = 0; k < 2; ++k)
                for (const bool top : {true, false}) {
                    const std::uint64_t m = top ? chan_[k].at_hi : chan_[k].at_lo;
                    if (static_cast<double>(m) > kPlateauShare * static_cast<double>(seen_))
                        return "bench: clipping at the input of " + device_ + ": " + fmt(100.0 * static_cast<double>(m) / static_cast<double>(seen_)) + " % of " + names[k] +
                               " samples (" + std::to_string(m) + " of " + std::to_string(seen_) + ") sit on its " + (top ? "largest" : "smallest") + " value, " +
                               fmt(top ? chan_[k].hi : chan_[k].lo) + " V, over " + fmt((th_max_ - th_min_) / kTwoPi) +
                               " electrical cycles (a sinusoid spends well under " + fmt(100 * kPlateauShare) +
                               " % of a cycle there: the input range is smaller than the signal; not a fault of the DUT)";
                }
        return "";
    }

    std::unique_ptr<FrameSource> inner_;
    std::string device_;
    std::uint64_t total_, seen_ = 0;
    double rail_v_ = 0, step_v_ = 0;
    Chan chan_[2];
    double last_s_ = kNaN, last_c_ = kNaN, run_theta0_ = kNaN;
    std::size_t run_ = 0;
    std::uint64_t run_start_ = 0;
    double th_min_ = std::numeric_limits<double>::infinity(), th_max_ = -std::numeric_limits<double>::infinity();
    std::vector<double> prev_, prev_c_;
    bool prev_truth_known_ = false;
    double prev_theta0_ = 0;
};

// Simulated devices (loopback) and captures carry the scenario's own model of clipping (the
// preflight warns of it); the checks are for bench hardware.
bool bench_hardware(const dev::DeviceInfo& i) { return i.driver != "loopback" && i.driver != "capture"; }

}  // namespace

void Frames::resize(std::size_t n, bool dut) {
    t_s.resize(n); sin_v.resize(n); cos_v.resize(n);
    theta_true_rad.resize(n); omega_true_rad_s.resize(n); truth_known.resize(n);
    dut_theta_rad.resize(dut ? n : 0);
}

std::unique_ptr<FrameSource> make_frame_source(const Scenario& sc, dev::Device& device, const dev::DeviceInfo& info,
                                               std::size_t block) {
    // The source follows from the ports the device has, in this order: a generator and a
    // digitizer in one (instrument mode), step mode without streams (a device with both, the
    // loopback, streams), streams, a replay. A step-only device is never asked to stream.
    std::unique_ptr<FrameSource> s;
    dev::PlayPort* play = device.player();
    dev::RecordPort* record = device.recorder();
    dev::StreamPort* stream = device.stream();
    dev::StepPort* step = device.step();
    if (play && record) s = std::make_unique<InstrumentSource>(sc, *play, *record);
    else if (step && !stream) s = std::make_unique<StepSource>(sc, *step, info.dut_position);
    else if (stream) s = std::make_unique<StreamSource>(sc, *stream, info, block);
    else if (dev::ReplayPort* replay = device.replay()) return std::make_unique<ReplaySource>(sc, *replay, info.dut_position);
    else if (play || record)
        throw std::runtime_error("device: " + info.uri + (play ? " is a generator without a digitizer: give device.output and device.input (instrument mode)"
                                                               : " is a digitizer without a generator: give device.output and device.input (instrument mode)"));
    else throw std::runtime_error("device: " + info.uri + " has no port to run through (no stream, step, play/record or replay)");
    if (bench_hardware(info)) s = std::make_unique<BenchChecks>(std::move(s), info, sc.samples());
    return s;
}

}  // namespace fringe

namespace fringe {

std::unique_ptr<FrameSource> make_instrument_source(const Scenario& sc, dev::Device& output, dev::Device& input) {
    dev::PlayPort* play = output.player();
    dev::RecordPort* record = input.recorder();
    const dev::DeviceInfo in = input.info();
    if (!play) throw std::runtime_error("device.output: " + output.info().uri + " cannot play a waveform from memory (not a generator; a loopback needs own_clock=1)");
    if (!record) throw std::runtime_error("device.input: " + in.uri + " cannot record a block (not a digitizer; a loopback needs own_clock=1)");
    std::unique_ptr<FrameSource> s = std::make_unique<InstrumentSource>(sc, *play, *record);
    if (bench_hardware(in)) s = std::make_unique<BenchChecks>(std::move(s), in, sc.samples());
    return s;
}

}  // namespace fringe
