// The run plan (server/engine/plan.hpp): a scenario is checked once, and each estimator under
// test is constructed once per run, whichever face runs it: a scenario through execute_run, a
// plan made first (fringe run, POST runs), a sweep row and a capture evaluation.
#include "helpers.hpp"

#include "estimator/estimator.hpp"
#include "server/engine/capture_run.hpp"
#include "server/engine/plan.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/engine/sweep.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>
#include <fstream>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_plan_cpp {

using namespace fringe;
using nlohmann::json;

namespace {

// atan2 of the pair, unwrapped; counts how many of it were ever constructed.
class CountedAtan2 final : public est::Estimator {
public:
    static inline std::atomic<int> constructed{0};
    CountedAtan2() { ++constructed; }
    void reset(const est::EstimatorConfig&) override { have_ = false; }
    void process(est::InputSpan in, est::OutputSpan out) override {
        for (std::size_t i = 0; i < in.size(); ++i) {
            const double w = std::atan2(in.sin_v[i], in.cos_v[i]);
            if (have_) {
                double d = w - last_;
                d -= kTwoPi * std::round(d / kTwoPi);
                unwrapped_ += d;
            } else {
                unwrapped_ = w;
                have_ = true;
            }
            last_ = w;
            out.theta_rad[i] = unwrapped_;
            out.omega_rad_s[i] = std::numeric_limits<double>::quiet_NaN();
            out.valid[i] = 1;
        }
    }
    est::BoundClass bound_class() const override { return est::BoundClass::Memoryless; }

private:
    double unwrapped_ = 0, last_ = 0;
    bool have_ = false;
};

est::EstimatorInfo counted_info() {
    return {"test-counted", "atan2 that counts its constructions (a test)", {}, [] { return std::make_unique<CountedAtan2>(); }, {}};
}

json scenario_json(const json& estimators) {
    return json{{"name", "plan"},
                {"encoder", std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders/ideal.json"},
                {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 50.0}}},
                {"sample_rate_hz", 20000},
                {"duration_s", 0.2},
                {"seed", 3},
                {"settle_s", 0.02},
                {"device", "loopback:?dac_bits=16&adc_bits=16"},
                {"estimators", estimators}};
}

const json kTwoLanes = json::array({json{{"name", "test-counted"}, {"label", "a"}}, json{{"name", "test-counted"}, {"label", "b"}}});

}  // namespace

TEST_CASE("plan: each estimator is constructed once per run", "[plan][run]") {
    est::ScopedEstimator scoped(counted_info());
    const Scenario sc = scenario_from_json(scenario_json(kTwoLanes), "");

    SECTION("a scenario through execute_run") {
        CountedAtan2::constructed = 0;
        const json r = execute_run(sc);
        CHECK(r["status"] == "done");
        CHECK(r["estimators"].size() == 2);
        CHECK(CountedAtan2::constructed == 2);
    }
    SECTION("a plan made first, then executed (fringe run, POST runs)") {
        CountedAtan2::constructed = 0;
        RunPlan plan = plan_run(sc);
        CHECK(CountedAtan2::constructed == 2);
        REQUIRE(plan.estimators.size() == 2);
        CHECK(plan.estimators[0] != nullptr);
        const json r = execute_run(std::move(plan));
        CHECK(r["status"] == "done");
        CHECK(CountedAtan2::constructed == 2);  // the run used the plan's
    }
    SECTION("a refused scenario builds what it checked and runs nothing") {
        Scenario bad = sc;
        bad.limits.push_back({"nobody", "rms_rad", 1.0, std::nullopt, 0.0});
        CountedAtan2::constructed = 0;
        CHECK_THROWS_WITH(plan_run(bad), Catch::Contains("limits[0].estimator"));
        CHECK(CountedAtan2::constructed == 2);
    }
    SECTION("a run beyond a service's budget builds nothing") {
        CountedAtan2::constructed = 0;
        RunBudget one;
        one.max_estimators = 1;
        try {
            plan_run(sc, one);
            FAIL("planned beyond the budget");
        } catch (const RunTooLarge& e) {
            CHECK(e.code() == "too_many_estimators");
            CHECK(e.field() == "estimators");
        }
        RunBudget few;
        few.max_samples = 100;
        CHECK_THROWS_AS(plan_run(sc, few), RunTooLarge);
        CHECK(CountedAtan2::constructed == 0);
    }
}

TEST_CASE("plan: a sweep row and a capture evaluation construct their estimator once", "[plan][run][sweep]") {
    est::ScopedEstimator scoped(counted_info());
    test::TempDir dir("fringe-plan");

    SECTION("sweep rows") {
        json base = scenario_json(json::array({json{{"name", "test-counted"}, {"label", "a"}}}));
        const json sweep{{"name", "plan-sweep"},
                         {"base", base},
                         {"columns", json::array({json{{"estimator", "a"}, {"metric", "rms_rad"}}})},
                         {"rows", json::array({json{{"set", {{"seed", 1}}}}, json{{"set", {{"seed", 2}}}}, json{{"set", {{"seed", 3}}}}})}};
        const std::string path = (dir.path / "sweep.json").string();
        std::ofstream(path) << sweep.dump();
        CountedAtan2::constructed = 0;
        const Sweep s = load_sweep(path);
        CHECK(CountedAtan2::constructed == 3);  // each row planned once, to check it
        auto res = run_sweep(s, 2);
        REQUIRE(res.size() == 3);
        for (const auto& row : res) CHECK(row.status == "done");
        CHECK(CountedAtan2::constructed == 3);  // the rows' runs executed those plans
        res = run_sweep(s, 1);  // run again: planned again, once per row
        for (const auto& row : res) CHECK(row.status == "done");
        CHECK(CountedAtan2::constructed == 6);
    }
    SECTION("a capture") {
        // A capture with truth, recorded from a loopback run of plain atan2.
        const std::string capture = (dir.path / "run.csv").string();
        RunOptions ro;
        ro.record_path = capture;
        REQUIRE(json(execute_run(scenario_from_json(scenario_json(json::array({json{{"name", "atan2"}}})), ""), ro))["status"] == "done");
        CaptureRunOptions o;
        o.capture_path = capture;
        o.estimator = "test-counted";
        o.settle_s = 0.02;
        CountedAtan2::constructed = 0;
        const json r = run_capture(o);
        CHECK(r["status"] == "done");
        CHECK(r["estimators"].size() == 1);
        CHECK(CountedAtan2::constructed == 1);
    }
}

}  // namespace test_plan_cpp
