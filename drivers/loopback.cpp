// loopback: the fully simulated converter chain (docs/schema.md "Devices"):
//   DAC (bits, range; zero-order hold at the stream rate) -> reconstruction filter (1st order)
//   -> analog noise -> anti-alias filter (1st or 2nd order Butterworth) -> ADC (bits, range,
//   clipping) -> latency. Fault injection for tests: drop samples, stall, saturate.
// Samples are processed when written, so read() only hands out what the chain produced.
// own_clock=1 turns it into a generator and a digitizer on separate clocks (instrument mode,
// issue 14): play() keeps the DAC codes, record() resamples them band-limited at the
// digitizer's sample times as seen on the generator's clock, delayed, with gain, offset,
// noise and the ADC (docs/alignment.md). Output and input are one instance: a run gives the
// same URI as device.output and device.input (or the URI alone as device).
#include "device.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/ring.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/noise.hpp"
#include "signal_gen/quantizer.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>

namespace fringe::dev {

namespace {

// Bilinear-transform low-pass sections with prewarping (exact cutoff).
struct Biquad {
    double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0, z1 = 0, z2 = 0;
    double step(double x) {  // transposed direct form II
        const double y = b0 * x + z1;
        z1 = b1 * x - a1 * y + z2;
        z2 = b2 * x - a2 * y;
        return y;
    }
    // No cutoff: y = x + z1 with the state staying zero (for finite input).
    bool passes() const { return b0 == 1 && b1 == 0 && b2 == 0 && a1 == 0 && a2 == 0 && z1 == 0 && z2 == 0; }
    static Biquad lowpass(int order, double fc_hz, double fs_hz) {
        Biquad q;
        if (fc_hz <= 0) return q;
        const double k = std::tan(kPi * fc_hz / fs_hz);
        if (order == 1) {
            const double n = 1 / (1 + k);
            q.b0 = q.b1 = k * n;
            q.a1 = (k - 1) * n;
        } else {
            const double sq2 = std::sqrt(2.0), n = 1 / (1 + sq2 * k + k * k);
            q.b0 = k * k * n; q.b1 = 2 * q.b0; q.b2 = q.b0;
            q.a1 = 2 * (k * k - 1) * n;
            q.a2 = (1 - sq2 * k + k * k) * n;
        }
        return q;
    }
};

// Without own_clock a stream and a step port; with it a generator and a digitizer (play and
// record ports) and nothing else.
class Loopback final : public Device, public StreamPort, public StepPort, public PlayPort, public SequencePort, public RecordPort {
public:
    Loopback(std::string uri, const nlohmann::json& s) : uri_(std::move(uri)), s_(s) {
        const double range = s.at("range_v").get<double>();
        dac_ = Quantizer{s.at("dac_bits").get<int>(), -range, range};
        adc_ = Quantizer{s.at("adc_bits").get<int>(), -range, range};
        latency_ = s.at("latency_samples").get<int>();
        // The chain's own noise: a real DAC-to-ADC path is never noise-free, and without it an
        // ADC whose decision points fall on the DAC's grid rounds every tie the same way (a
        // 16-bit DAC into a 14-bit ADC: a DC shift of half a DAC step, a 1x error harmonic that
        // is not there). noise_lsb is in LSB of the finer converter; noise_v adds in quadrature.
        const double q_fine = fine_step_v();
        noise_v_ = std::hypot(s.at("noise_v").get<double>(), s.at("noise_lsb").get<double>() * q_fine);
        const auto seed = static_cast<std::uint64_t>(s.at("seed").get<long long>());
        rng_ = Xoshiro256pp(seed);
        noise_ = NoiseField(seed, kLoopbackNoiseStream, 2);
        drop_after_ = s.at("drop_after").get<long long>();
        drop_count_ = s.at("drop_count").get<long long>();
        stall_after_ = s.at("stall_after").get<long long>();
        saturate_after_ = s.at("saturate_after").get<long long>();
        own_clock_ = s.at("own_clock").get<int>() != 0;
        delay_s_ = s.at("delay_s").get<double>();
        clock_ppm_ = s.at("clock_ppm").get<double>();
        gain_ = s.at("gain").get<double>();
        offset_v_ = s.at("offset_v").get<double>();
        cos_gain_ratio_ = s.at("cos_gain_ratio").get<double>();
        cos_offset_v_ = s.at("cos_offset_v").get<double>();
        swap_ = s.at("swap_channels").get<int>() != 0;
        max_play_ = static_cast<std::size_t>(s.at("max_play_samples").get<long long>());
        glitch_at_ = s.at("glitch_at").get<long long>();
        glitch_v_ = s.at("glitch_v").get<double>();
        max_segments_ = static_cast<std::size_t>(s.at("max_segments").get<long long>());
        join_slip_ = s.at("join_slip_samples").get<int>();
        fail_at_segment_ = s.at("fail_at_segment").get<long long>();
    }
    // LSB (V) of the finer of the two converters; 0 when both are ideal.
    double fine_step_v() const {
        double q = 0;
        for (const Quantizer* z : {&dac_, &adc_})
            if (!z->ideal()) q = q > 0 ? std::min(q, z->step_v()) : z->step_v();
        return q;
    }
    // The ADC: nearest level, ties to even. floor(x + 1/2) sends every tie up, and a DAC grid
    // finer than the ADC's by a power of two lands on the ADC's decision points exactly; ties
    // to even split them evenly, so even a noise-free chain adds no offset of its own.
    double adc_read(double v) const {
        if (adc_.ideal()) return v;
        return adc_.min_v + Quantizer::clamp_code(std::nearbyint((v - adc_.min_v) * adc_.inv_step()), adc_.max_code()) * adc_.step_v();
    }
    StreamPort* stream() override { return own_clock_ ? nullptr : this; }
    StepPort* step() override { return own_clock_ ? nullptr : this; }
    PlayPort* player() override { return own_clock_ ? this : nullptr; }
    RecordPort* recorder() override { return own_clock_ ? this : nullptr; }

    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "loopback";
        i.uri = uri_;
        i.description = "simulated DAC -> filters -> noise -> ADC";
        i.board_id = "loopback";
        i.latency_samples = latency_;
        i.output_ahead_blocks = 1;  // simulated: the input never waits for a clock
        i.settings = s_;
        if (own_clock_) {
            i.description = "simulated generator and digitizer on separate clocks: delay, clock offset, gain, offset, noise, DAC and ADC";
            i.own_clock = true;
            i.latency_samples = 0;
        }
        i.converter.known = true;
        i.converter.dac_bits = dac_.bits;
        i.converter.adc_bits = adc_.bits;
        i.converter.dac_range_v = i.converter.adc_range_v = adc_.max_v;
        // White analog noise through the anti-alias filter: its variance scales by sum h[n]^2.
        const double fs = fs_ > 0 ? fs_ : 0.0;
        double gain2 = 1.0;
        if (fs > 0 && s_.at("aa_cutoff_hz").get<double>() > 0) {
            Biquad f = Biquad::lowpass(s_.at("aa_order").get<int>(), s_.at("aa_cutoff_hz").get<double>(), fs);
            gain2 = 0;
            for (int n = 0; n < 200000; ++n) {
                const double h = f.step(n == 0 ? 1.0 : 0.0);
                gain2 += h * h;
                if (n > 64 && std::fabs(h) < 1e-12) break;
            }
        }
        i.converter.noise_at_adc_v = noise_v_ * std::sqrt(gain2);
        if (fs <= 0 && s_.at("aa_cutoff_hz").get<double>() > 0) i.converter.note = "noise before the anti-alias filter (not started)";
        else i.converter.note = "filters' effect on the signal amplitude is not in the bound";
        // With little noise between them, an ADC on the DAC's own grid reads back the DAC's
        // codes (filters only blur the steps between held codes): no quantisation of its own.
        // Measured: 8-bit DAC and ADC, with or without a 40 kHz anti-alias filter, give the
        // 8-bit DAC's error alone to 10 digits (tests/test_evidence.cpp).
        const double qd = i.converter.dac_q_v(), qa = i.converter.adc_q_v(), n = i.converter.noise_at_adc_v;
        if (own_clock_) {  // resampled between the grids: the ADC quantises independently
            i.converter.note = "own clock: DAC codes resampled band-limited at the digitizer's times; DAC and ADC quantise independently";
            i.converter.added_noise_v = i.converter.independent_noise_v();
        } else if (dac_.bits > 0 && dac_.bits == adc_.bits && n < qa / 4) {
            i.converter.added_noise_v = std::sqrt(qd * qd / 12 + n * n);
            i.converter.note += "; the ADC re-reads the DAC's grid (same bits and range, analog noise < q/4): one quantisation";
        } else {
            i.converter.added_noise_v = i.converter.independent_noise_v();
        }
        return i;
    }
    void start(double fs) override {
        if (!(fs > 0)) throw DeviceError(uri_, "sample rate must be positive");
        fs_ = fs;
        for (int ch = 0; ch < 2; ++ch) {
            recon_[ch] = Biquad::lowpass(1, s_.at("recon_cutoff_hz").get<double>(), fs);
            aa_[ch] = Biquad::lowpass(s_.at("aa_order").get<int>(), s_.at("aa_cutoff_hz").get<double>(), fs);
        }
        queue_.clear();
        for (int k = 0; k < latency_; ++k) {
            const double z = adc_read(0.0);
            queue_.push(1, &z, &z, 0);
        }
        written_ = read_ = 0;
        pending_drop_ = 0;
        last_update_ = -1;
        dac_rate_hz_ = s_.at("dac_rate_hz").get<double>();
        if (dac_rate_hz_ > fs) throw DeviceError(uri_, "dac_rate_hz above the stream rate is not simulated (it must be <= the sample rate)");
        running_ = true;
    }
    StreamResult write(std::span<const double> s, std::span<const double> c) override {
        if (!running_) throw DeviceError(uri_, "write before start");
        // A block at a time, in passes, with the same arithmetic per sample as the chain below
        // read sample by sample: the DAC codes held, the noise drawn in its order (sin then
        // cos per sample), each channel through its filters, then the ADC.
        for (std::size_t off = 0; off < s.size(); off += kChunk) write_chunk(s.subspan(off, std::min(kChunk, s.size() - off)), c.subspan(off, std::min(kChunk, c.size() - off)));
        return {StreamStatus::Ok, s.size(), 0, 0, {}};
    }
    StreamResult read(std::span<double> s, std::span<double> c, int) override {
        StreamResult r;
        r.first_index = read_ + dropped_total_;
        const std::uint64_t gap = !queue_.empty() ? queue_.gap_at_front() : pending_drop_;
        if (gap > 0) {  // samples were lost just before the next frame
            const auto lost = gap;
            if (!queue_.empty()) queue_.clear_front_gap(); else pending_drop_ = 0;
            r.status = StreamStatus::Overflow;
            r.dropped = lost;
            dropped_total_ += lost;
            r.first_index = read_ + dropped_total_;
            r.message = std::to_string(lost) + " input samples lost (injected: drop_after/drop_count)";
            return r;
        }
        if (stall_after_ >= 0 && static_cast<long long>(read_) >= stall_after_) {
            r.status = StreamStatus::Timeout;
            r.message = "no input after sample " + std::to_string(read_) + " (injected: stall_after)";
            return r;
        }
        std::size_t n = std::min(s.size(), queue_.size());
        n = std::min(n, queue_.frames_before_next_gap());  // stop before the next gap
        if (stall_after_ >= 0) n = std::min<std::size_t>(n, static_cast<std::size_t>(stall_after_ - static_cast<long long>(read_)));
        queue_.pop(n, s.data(), c.data());
        read_ += n;
        r.frames = n;
        return r;
    }
    void stop() override { running_ = false; }
    StepResult measure(double s, double c, double settle_s, int average) override {
        // Static pair: the filters settle (run settle_s of samples), then average ADC reads.
        if (!running_) start(fs_ > 0 ? fs_ : 100e3);
        const auto settle = static_cast<std::size_t>(std::ceil(std::max(settle_s, 0.0) * fs_)) + static_cast<std::size_t>(latency_);
        const std::size_t n = settle + static_cast<std::size_t>(std::max(average, 1));
        std::vector<double> vs(n, s), vc(n, c), rs(n), rc(n);
        write(vs, vc);
        std::size_t got = 0;
        while (got < n) {
            const auto r = read(std::span(rs).subspan(got), std::span(rc).subspan(got), 0);
            if (r.status != StreamStatus::Ok) throw DeviceError(uri_, std::string("step: ") + to_string(r.status) + ": " + r.message);
            if (!r.frames) break;
            got += r.frames;
        }
        StepResult out;
        const std::size_t m = static_cast<std::size_t>(std::max(average, 1));
        for (std::size_t i = n - m; i < n; ++i) { out.sin_v += rs[i] / static_cast<double>(m); out.cos_v += rc[i] / static_cast<double>(m); }
        return out;
    }

    SequencePort* sequencer() override { return own_clock_ && max_segments_ > 0 ? this : nullptr; }
    std::string sequence_refusal() const override { return "the simulated generator plays segments only with max_segments > 0"; }
    SequenceLimits sequence_limits() const override {
        return {max_segments_, kMinSegment, max_play_ > 0 ? max_play_ : std::numeric_limits<std::size_t>::max()};
    }
    // A streaming generator: each segment is loaded into its memory while the one before it
    // plays, so the output is the whole signal, sample-continuous. Faults: join_slip_samples
    // drops (-1) or repeats (+1) one sample at every join; fail_at_segment ends the output
    // there (the generator lost mid-sequence), which the next record() reports.
    void play_segments(std::span<const double> s, std::span<const double> c, std::size_t seg, double fs) override {
        if (s.size() != c.size() || s.empty()) throw DeviceError(uri_, "play_segments: sin and cos must have the same, non-zero length");
        if (!(fs > 0)) throw DeviceError(uri_, "play_segments: sample rate must be positive");
        const SequenceLimits lim = sequence_limits();
        const std::size_t n = (s.size() + seg - 1) / std::max<std::size_t>(seg, 1);
        const std::size_t last = s.size() - (n - 1) * seg;
        if (seg < lim.min_segment_samples || seg > lim.max_segment_samples || last < lim.min_segment_samples || n > lim.max_segments)
            throw DeviceError(uri_, "play_segments: " + std::to_string(n) + " segments of " + std::to_string(seg) + " samples (the last " + std::to_string(last) +
                                        ") break the generator's limits: at most " + std::to_string(lim.max_segments) + " segments (max_segments) of " +
                                        std::to_string(lim.min_segment_samples) + ".." + std::to_string(lim.max_segment_samples) + " samples (max_play_samples)");
        for (auto& p : played_) p.clear();
        segments_ = n;
        failed_at_.reset();
        for (std::size_t i = 0; i < n; ++i) {
            if (fail_at_segment_ >= 0 && static_cast<long long>(i) == fail_at_segment_) {
                failed_at_ = i;  // segments 0..i-1 played
                break;
            }
            const std::size_t a = i * seg, b = std::min(s.size(), a + seg);
            std::size_t from = a;
            if (i > 0 && join_slip_ < 0) from = a + 1;  // the join loses the segment's first sample
            if (i > 0 && join_slip_ > 0) { played_[0].push_back(played_[0].back()); played_[1].push_back(played_[1].back()); }
            for (std::size_t k = from; k < b; ++k) { played_[0].push_back(dac_.apply(s[k])); played_[1].push_back(dac_.apply(c[k])); }
        }
        play_fs_ = fs;
        cyclic_ = false;
    }

    void play(std::span<const double> s, std::span<const double> c, double fs, bool cyclic) override {
        if (s.size() != c.size() || s.empty()) throw DeviceError(uri_, "play: sin and cos must have the same, non-zero length");
        segments_ = 0;
        failed_at_.reset();
        if (!(fs > 0)) throw DeviceError(uri_, "play: sample rate must be positive");
        if (max_play_ > 0 && s.size() > max_play_)
            throw DeviceError(uri_, "play: " + std::to_string(s.size()) + " samples per channel exceed the generator memory (max_play_samples " +
                                        std::to_string(max_play_) + ")");
        played_[0].resize(s.size());
        played_[1].resize(c.size());
        for (std::size_t i = 0; i < s.size(); ++i) { played_[0][i] = dac_.apply(s[i]); played_[1][i] = dac_.apply(c[i]); }
        play_fs_ = fs;
        cyclic_ = cyclic;
    }
    StreamResult record(std::span<double> s, std::span<double> c, double fs, double) override {
        if (played_[0].empty())
            throw DeviceError(uri_, "record: nothing was played on this loopback (its output and input are one instance: "
                                    "give the same URI as device.output and device.input)");
        if (!(fs > 0)) throw DeviceError(uri_, "record: sample rate must be positive");
        if (failed_at_)
            throw DeviceError(uri_, "the generator was lost when segment " + std::to_string(*failed_at_) + " of " + std::to_string(segments_) +
                                        " (0-based) was due (fail_at_segment): the output ended mid-sequence after " + std::to_string(*failed_at_) + " segments");
        // Sample m is taken at digitizer time m/fs; it shows what the generator emitted delay_s
        // earlier, on a generator clock running clock_ppm fast.
        const double k = 1 + clock_ppm_ * 1e-6;
        const double g[2] = {gain_, gain_ * cos_gain_ratio_}, o[2] = {offset_v_, offset_v_ + cos_offset_v_};
        const std::size_t n = std::min(s.size(), c.size());
        for (std::size_t m = 0; m < n; ++m) {
            const double u = (static_cast<double>(m) / fs - delay_s_) * k * play_fs_;  // generator sample position
            double v[2];
            resample(u, v);
            for (int ch = 0; ch < 2; ++ch) {
                double a = g[ch] * v[ch] + o[ch];
                if (noise_v_ > 0) a += noise_v_ * standard_normal(rng_);
                if (adc_.clips(a)) ++clipped_;
                v[ch] = adc_read(a);
            }
            s[m] = swap_ ? v[1] : v[0];
            c[m] = swap_ ? v[0] : v[1];
            if (static_cast<long long>(m) == glitch_at_) s[m] = glitch_v_;  // one corrupt sample, past the ADC
        }
        return {StreamStatus::Ok, n, 0, 0, {}};
    }
    // The emulated generator's memory holds the block; nothing runs on after a record.
    void stop_output() override {}
    std::size_t memory_samples() const override { return max_play_; }

private:
    // Band-limited value of the played codes at generator sample position u (0 V before the
    // output starts, and after it ends unless cyclic): Blackman-Harris-windowed sinc, 32 taps a
    // side, computed directly. Deliberately not the aligner's interpolator (server/analysis/align.cpp
    // uses a tabulated Kaiser-windowed sinc), so the tests do not grade it against itself.
    void resample(double u, double* v) const {
        constexpr int H = 32;
        v[0] = v[1] = 0;
        const auto n = static_cast<long long>(played_[0].size());
        if (!(u > -H) || (!cyclic_ && u >= static_cast<double>(n) - 1 + H)) return;
        const double fl = std::floor(u), f = u - fl;
        const auto n0 = static_cast<long long>(fl);
        const double sf = std::sin(kPi * f);
        for (int k = -H + 1; k <= H; ++k) {
            long long idx = n0 + k;
            if (idx < 0) continue;
            if (idx >= n) {
                if (!cyclic_) break;
                idx %= n;
            }
            const double x = f - k;
            const double sinc = std::fabs(x) < 1e-12 ? 1.0 : ((k & 1) ? -sf : sf) / (kPi * x);
            const double y = kTwoPi * (x + H) / (2.0 * H);  // window argument over [-H, H]
            const double w = 0.35875 - 0.48829 * std::cos(y) + 0.14128 * std::cos(2 * y) - 0.01168 * std::cos(3 * y);
            v[0] += played_[0][static_cast<std::size_t>(idx)] * sinc * w;
            v[1] += played_[1][static_cast<std::size_t>(idx)] * sinc * w;
        }
    }

    static constexpr std::size_t kChunk = 4096;
    void write_chunk(std::span<const double> s, std::span<const double> c) {
        const std::size_t m = s.size();
        for (auto* v : {&h_[0], &h_[1], &a_[0], &a_[1]}) v->resize(m);
        // The DAC: a new code is latched when floor(k*dac_rate/fs) advances (zero-order hold in
        // between); dac_rate 0 means every sample.
        if (dac_rate_hz_ > 0) {
            for (std::size_t i = 0; i < m; ++i) {
                const long long k = static_cast<long long>(written_ + i);
                const std::int64_t u = static_cast<std::int64_t>(std::floor(static_cast<double>(k) * dac_rate_hz_ / fs_));
                if (u != last_update_) {
                    held_[0] = dac_.apply(s[i]);
                    held_[1] = dac_.apply(c[i]);
                    last_update_ = u;
                }
                h_[0][i] = held_[0];
                h_[1][i] = held_[1];
            }
        } else if (m) {
            const Quantizer d = dac_;
            const bool ideal = d.ideal();
            const double lo = d.min_v, inv = ideal ? 0.0 : d.inv_step(), q = ideal ? 0.0 : d.step_v(), top = ideal ? 0.0 : d.max_code();
            for (int ch = 0; ch < 2; ++ch) {
                const double* x = ch ? c.data() : s.data();
                double* h = h_[ch].data();
                if (ideal) std::copy(x, x + m, h);
                else
                    for (std::size_t i = 0; i < m; ++i) h[i] = Quantizer::quantize(x[i], lo, inv, q, top);
            }
            held_[0] = h_[0][m - 1];
            held_[1] = h_[1][m - 1];
            last_update_ = static_cast<std::int64_t>(written_ + m - 1);
        }
        // The noise: normal number ch of stream sample k, a function of (seed, k) alone
        // (counter-based, NoiseField), so any split into blocks gives the same samples; drawn
        // sixteen at a time where the CPU has AVX-512.
        const bool noisy = noise_v_ > 0;
        const double* zs[2] = {nullptr, nullptr};
        if (noisy && !noise_.view(written_, m, zs)) {
            nz_[0].resize(m);
            nz_[1].resize(m);
            double* out[2] = {nz_[0].data(), nz_[1].data()};
            noise_.fill(written_, m, out);
            zs[0] = nz_[0].data();
            zs[1] = nz_[1].data();
        }
        // Each channel through its filters. A filter with no cutoff passes its input through
        // (y = x + 0, its state stays zero while the input is finite): skipped then, unless the
        // sign of a zero could reach the output (an ideal ADC) or an input is not finite.
        std::size_t not_finite = 0;
        for (int ch = 0; ch < 2; ++ch) {
            const double* h = h_[ch].data();
            for (std::size_t i = 0; i < m; ++i) not_finite += !((h[i] - h[i]) == 0.0);  // NaN unless finite (a pass that vectorises)
        }
        const bool finite = not_finite == 0;
        const bool direct = finite && !adc_.ideal() && recon_[0].passes() && aa_[0].passes() && recon_[1].passes() && aa_[1].passes();
        const double nv = noise_v_;
        for (int ch = 0; ch < 2; ++ch) {
            const double* h = h_[ch].data();
            double* a = a_[ch].data();
            const double* z = zs[ch];
            if (direct) {
                if (noisy)
                    for (std::size_t i = 0; i < m; ++i) a[i] = h[i] + nv * z[i];
                else
                    std::copy(h, h + m, a);
            } else {
                Biquad r = recon_[ch], f = aa_[ch];
                for (std::size_t i = 0; i < m; ++i) {
                    double x = r.step(h[i]);
                    if (noisy) x += nv * z[i];
                    a[i] = f.step(x);
                }
                recon_[ch] = r;
                aa_[ch] = f;
            }
        }
        // Driven into the rail from saturate_after on.
        if (saturate_after_ >= 0)
            for (std::size_t i = 0; i < m; ++i)
                if (static_cast<long long>(written_ + i) >= saturate_after_) a_[0][i] = a_[1][i] = 2 * adc_.max_v;
        // The ADC (nearest level, ties to even; see adc_read), counting samples past its rails.
        if (!adc_.ideal()) {
            const double lo = adc_.min_v, inv = adc_.inv_step(), q = adc_.step_v(), top = adc_.max_code();
            std::uint64_t clipped = 0;
            for (int ch = 0; ch < 2; ++ch) {
                double* a = a_[ch].data();
                for (std::size_t i = 0; i < m; ++i) {
                    const double raw = std::floor((a[i] - lo) * inv + 0.5);  // Quantizer::clips
                    clipped += raw < 0.0 || raw > top;
                    const double code = std::nearbyint((a[i] - lo) * inv);
                    a[i] = lo + (code < 0.0 ? 0.0 : (code > top ? top : code)) * q;
                }
            }
            clipped_ += clipped;
        }
        // Into the FIFO, less the samples lost on the way in (the gap is reported where it happened).
        std::size_t i = 0;
        while (i < m) {
            const long long k = static_cast<long long>(written_ + i);
            if (drop_after_ >= 0 && k >= drop_after_ && k < drop_after_ + drop_count_) {
                ++pending_drop_;
                ++i;
                continue;
            }
            // The run of kept samples from i: up to the next dropped one.
            std::size_t j = m;
            if (drop_after_ >= 0 && k < drop_after_ && drop_count_ > 0) j = std::min<std::size_t>(m, i + static_cast<std::size_t>(drop_after_ - k));
            queue_.push(j - i, a_[0].data() + i, a_[1].data() + i, pending_drop_);
            pending_drop_ = 0;
            i = j;
        }
        written_ += m;
    }

    std::string uri_;
    nlohmann::json s_;
    Quantizer dac_, adc_;
    Biquad recon_[2], aa_[2];
    int latency_ = 0;
    double noise_v_ = 0, fs_ = 0;
    Xoshiro256pp rng_{1};  // the play/record path's noise, drawn in order
    // The stream path's noise (write): its own stream id, so that it is not the generator's
    // (stream 1) when the loopback's seed and the scenario's are the same.
    static constexpr std::uint64_t kLoopbackNoiseStream = 0x6c6f6f70ULL;  // "loop"
    NoiseField noise_{1, kLoopbackNoiseStream, 2};
    // The chain's output: sin and cos in two rings (a deque allocated and freed a chunk every
    // 512 samples), and the gaps (samples lost just before a frame) by the frame's position in
    // the stream of frames pushed.
    struct Fifo {
        Ring<double> s, c;
        std::uint64_t popped = 0;  // frames popped since the start
        std::deque<std::pair<std::uint64_t, std::uint64_t>> gaps;  // (frame position, samples lost before it)
        bool empty() const { return s.empty(); }
        std::size_t size() const { return s.size(); }
        std::uint64_t gap_at_front() const { return !gaps.empty() && gaps.front().first == popped ? gaps.front().second : 0; }
        void clear_front_gap() {
            if (gap_at_front()) gaps.pop_front();
        }
        // Frames from the front before the next one preceded by a gap (the front's own gap aside).
        std::size_t frames_before_next_gap() const {
            for (const auto& g : gaps)
                if (g.first > popped) return static_cast<std::size_t>(g.first - popped);
            return size();
        }
        void push(std::size_t n, const double* vs, const double* vc, std::uint64_t gap_before) {
            if (!n) return;
            if (gap_before) gaps.emplace_back(popped + size(), gap_before);
            s.push(vs, n);
            c.push(vc, n);
        }
        void clear() {
            s.clear();
            c.clear();
            popped = 0;
            gaps.clear();
        }
        void pop(std::size_t n, double* vs, double* vc) {
            s.pop(vs, n);
            c.pop(vc, n);
            popped += n;
        }
    };
    Fifo queue_;
    std::vector<double> h_[2], a_[2], nz_[2];  // write's scratch per channel: held DAC output, ADC input, noise
    std::uint64_t written_ = 0, read_ = 0, pending_drop_ = 0, dropped_total_ = 0, clipped_ = 0;
    long long drop_after_ = -1, drop_count_ = 0, stall_after_ = -1, saturate_after_ = -1;
    bool running_ = false;
    double dac_rate_hz_ = 0, held_[2] = {0, 0};
    std::int64_t last_update_ = -1;
    // own_clock (instrument mode)
    bool own_clock_ = false, swap_ = false, cyclic_ = false;
    long long glitch_at_ = -1;
    double glitch_v_ = 0;
    double delay_s_ = 0, clock_ppm_ = 0, gain_ = 1, offset_v_ = 0, cos_gain_ratio_ = 1, cos_offset_v_ = 0, play_fs_ = 0;
    std::size_t max_play_ = 0;
    std::vector<double> played_[2];
    // Segmented playback (max_segments > 0): a streaming generator; faults at the joins.
    static constexpr std::size_t kMinSegment = 16;
    std::size_t max_segments_ = 0, segments_ = 0;
    int join_slip_ = 0;
    long long fail_at_segment_ = -1;
    std::optional<std::size_t> failed_at_;
};

}  // namespace

void register_loopback(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "loopback";
    d.summary = "Fully simulated converter chain: DAC, reconstruction filter, analog noise, anti-alias filter, ADC, latency; fault injection";
    d.settings = {
        {"dac_bits", "bit", ParamType::Integer, 16, 0, 24, {}, "DAC resolution (0: ideal)"},
        {"adc_bits", "bit", ParamType::Integer, 16, 0, 24, {}, "ADC resolution (0: ideal)"},
        {"range_v", "V", ParamType::Number, 1.25, 1e-3, 100, {}, "DAC and ADC full scale [-range_v, range_v)"},
        {"dac_rate_hz", "Hz", ParamType::Number, 0.0, 0, 1e10, {}, "DAC update rate, zero-order hold in between (0: the stream rate; at most the stream rate)"},
        {"recon_cutoff_hz", "Hz", ParamType::Number, 0.0, 0, 1e9, {}, "reconstruction filter (1st order) cutoff; 0: none"},
        {"aa_cutoff_hz", "Hz", ParamType::Number, 0.0, 0, 1e9, {}, "anti-alias filter cutoff; 0: none"},
        {"aa_order", "", ParamType::Integer, 2, 1, 2, {}, "anti-alias filter order (Butterworth)"},
        {"noise_v", "V", ParamType::Number, 0.0, 0, 10, {}, "analog noise per channel, rms (added in quadrature to noise_lsb's)"},
        {"noise_lsb", "LSB", ParamType::Number, 1.0, 0, 1000, {}, "the converter chain's own noise per channel, rms, in LSB of the finer converter (a real DAC-to-ADC path is never noise-free; 0: none)"},
        {"seed", "", ParamType::Integer, 1, 0, 9e15, {}, "analog noise seed"},
        {"latency_samples", "samples", ParamType::Integer, 0, 0, 1e6, {}, "pure delay from DAC to ADC"},
        {"drop_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: lose drop_count input samples from this index (-1: never)"},
        {"drop_count", "samples", ParamType::Integer, 0, 0, 9e15, {}, "fault: how many"},
        {"stall_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: no input after this many samples (-1: never)"},
        {"saturate_after", "samples", ParamType::Integer, -1, -1, 9e15, {}, "fault: drive the ADC into its rail from this index (-1: never)"},
        {"own_clock", "", ParamType::Integer, 0, 0, 1, {}, "1: a generator and a digitizer on separate clocks (plays and records blocks; the run aligns truth, docs/alignment.md)"},
        {"delay_s", "s", ParamType::Number, 0.0, -1.0, 10.0, {}, "own_clock: delay from the generator to the digitizer (negative: the record starts after the output)"},
        {"clock_ppm", "ppm", ParamType::Number, 0.0, -10000.0, 10000.0, {}, "own_clock: the generator's clock runs this much fast relative to the digitizer's"},
        {"gain", "", ParamType::Number, 1.0, -100.0, 100.0, {}, "own_clock: link gain, both channels"},
        {"offset_v", "V", ParamType::Number, 0.0, -100.0, 100.0, {}, "own_clock: link offset, both channels"},
        {"cos_gain_ratio", "", ParamType::Number, 1.0, -100.0, 100.0, {}, "own_clock: the cos channel's gain relative to gain (negative: inverted)"},
        {"cos_offset_v", "V", ParamType::Number, 0.0, -100.0, 100.0, {}, "own_clock: added to the cos channel's offset"},
        {"swap_channels", "", ParamType::Integer, 0, 0, 1, {}, "own_clock fault: the digitizer's inputs are swapped (sin records cos)"},
        {"max_play_samples", "samples", ParamType::Integer, 0, 0, 9e15, {}, "own_clock: generator memory per channel (0: unlimited)"},
        {"glitch_at", "samples", ParamType::Integer, -1, -1, 9e15, {}, "own_clock fault: the recorded sin sample at this index reads glitch_v (-1: never)"},
        {"glitch_v", "V", ParamType::Number, 1e300, -1e308, 1e308, {}, "own_clock fault: the value of that sample"},
        {"max_segments", "", ParamType::Integer, 0, 0, 1e9, {}, "own_clock: segmented playback of a run longer than max_play_samples, at most this many segments of 16..max_play_samples samples, played back to back like a streaming generator (0: none)"},
        {"join_slip_samples", "samples", ParamType::Integer, 0, -1, 1, {}, "own_clock fault: every segment join drops (-1) or repeats (+1) one sample"},
        {"fail_at_segment", "", ParamType::Integer, -1, -1, 1e9, {}, "own_clock fault: the generator is lost when this segment (0-based) is due (-1: never)"},
    };
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        if (!path.empty()) throw ConfigError("device", "loopback takes no path (got '" + path + "'); use loopback:?key=value");
        // Each mode refuses the other's settings rather than ignoring them.
        const bool own = s.at("own_clock").get<int>() != 0;
        static const std::vector<std::pair<std::string, double>> streaming_only = {
            {"dac_rate_hz", 0}, {"recon_cutoff_hz", 0}, {"aa_cutoff_hz", 0}, {"latency_samples", 0},
            {"drop_after", -1}, {"drop_count", 0}, {"stall_after", -1}, {"saturate_after", -1}};
        static const std::vector<std::pair<std::string, double>> own_only = {
            {"delay_s", 0}, {"clock_ppm", 0}, {"gain", 1}, {"offset_v", 0}, {"cos_gain_ratio", 1}, {"cos_offset_v", 0},
            {"swap_channels", 0}, {"max_play_samples", 0}, {"glitch_at", -1}, {"glitch_v", 1e300},
            {"max_segments", 0}, {"join_slip_samples", 0}, {"fail_at_segment", -1}};
        for (const auto& [key, def] : own ? streaming_only : own_only)
            if (s.at(key).get<double>() != def)
                throw ConfigError("device." + key, own ? key + " is not simulated with own_clock=1 (the generator/digitizer pair models delay, clock offset, gain, offset, noise and converters)"
                                                       : key + " needs own_clock=1 (a generator and a digitizer on separate clocks)");
        return std::make_unique<Loopback>(uri, s);
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
