// `omm calibrate` end to end on a rendered demo project (tests/sim_cache.h):
// the files it writes, python3-mrcal reading its camera, the report section,
// and reusing the calibration through `calibration.from`.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <regex>
#include <sstream>

#include "adapters/mrcal/cameramodel_io.h"
#include "adapters/mrcal/lens.h"
#include "adapters/project_io/report_json.h"
#include "tests/sim_cache.h"
#include "tests/test_util.h"

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

namespace omm {
namespace {

// (Built by append: GCC 12's -Wrestrict misfires on "'" + std::string at -O3.)
std::string Quoted(const fs::path& path) {
  return std::string("'").append(path.string()).append("'");
}

// python3-mrcal's reading of a written camera model: it prints the lens
// model and imager width it read, then its projection of camera-frame point
// p; `q` holds that projection once parsed.
struct MrcalReading {
  testing::CommandResult python;
  Eigen::Vector2d q = Eigen::Vector2d::Constant(NAN);
};

MrcalReading ReadWithPython3Mrcal(const fs::path& model, const Eigen::Vector3d& p) {
  std::ostringstream script;
  script.precision(17);
  script << "import mrcal, numpy; m = mrcal.cameramodel('" << model.string()
         << "'); q = mrcal.project(numpy.array((" << p.x() << ", " << p.y() << ", " << p.z()
         << "), dtype=float), *m.intrinsics()); print(m.intrinsics()[0], m.imagersize()[0]); "
         << "print('%.9f %.9f' % (q[0], q[1]))";
  MrcalReading reading;
  reading.python = testing::RunCommand("/usr/bin/python3 -c \"" + script.str() + "\"");
  std::istringstream last_line(reading.python.output.substr(
      reading.python.output.find_last_of('\n', reading.python.output.size() - 2) + 1));
  last_line >> reading.q.x() >> reading.q.y();
  return reading;
}

// One calibrated copy of the demo project shared by the tests below.
class CalibrateCliTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new testing::TempDir();
    const testing::CachedProject sim = testing::SimulatedProject("demo", 1);
    testing::CopyProject(sim.project_dir, Calibrated());
    calibrate_ = new testing::CommandResult(testing::RunOmm("calibrate " + Quoted(Calibrated())));
    std::cout << calibrate_->output;
  }
  static void TearDownTestSuite() {
    delete calibrate_;
    delete dir_;
  }
  static fs::path Calibrated() { return dir_->path() / "calibrated"; }

  // A copy of the demo project whose project.yaml reuses `from`.
  static fs::path Reusing(const std::string& name, const fs::path& from) {
    const fs::path dir = dir_->path() / name;
    testing::CopyProject(testing::SimulatedProject("demo", 1).project_dir, dir);
    std::string reuse = "\ncalibration:\n  from: ";
    reuse.append(from.string()).append("\nboard:");
    testing::ReplaceInFile(dir / "project.yaml", "\nboard:", reuse);
    return dir;
  }

  static testing::TempDir* dir_;
  static testing::CommandResult* calibrate_;
};

testing::TempDir* CalibrateCliTest::dir_ = nullptr;
testing::CommandResult* CalibrateCliTest::calibrate_ = nullptr;

TEST_F(CalibrateCliTest, WritesTheCameraSolveRecordPlotAndReport) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const fs::path out = Calibrated() / "out";
  EXPECT_TRUE(fs::exists(out / "camera.cameramodel"));
  EXPECT_TRUE(fs::exists(out / "calibration" / "solve.json"));
  EXPECT_THAT(testing::ReadTextFile(out / "calibration" / "residuals.svg"), HasSubstr("<svg"));
  const Report report = ReadReportJson(out / "report.json");
  ASSERT_TRUE(report.calibration);
  EXPECT_EQ(report.calibration->images_used, 18);
  EXPECT_EQ(report.calibration->images_rejected.size(), 2u);
  EXPECT_GT(report.calibration->rms_px, 0.0);
  EXPECT_LT(report.calibration->rms_px, 0.1);
  for (const char* key : {"intrinsics", "per_image", "outliers", "projection_uncertainty",
                          "lens_model_choice", "perspective_bias_correction", "residuals_plot"}) {
    EXPECT_NE(Member(report.calibration->extra, key), nullptr) << key;
  }
}

// The calibrated focal length against project.yaml's (camera.focal_length_mm
// 12, the rendered lens 12.16 mm: consistent), and a focal length typed 50
// for 12: warned about and reported, the calibration unchanged.
TEST_F(CalibrateCliTest, FocalLengthFarFromTheStatedOneIsWarnedAbout) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const double truth_mm = testing::SimulatedProject("demo", 1).truth.camera.focal_length_mm;
  const auto check_of = [](const fs::path& project) {
    const Report report = ReadReportJson(project / "out" / "report.json");
    const ReportObject* check =
        report.calibration ? AsObject(Member(report.calibration->extra, "focal_length_check"))
                           : nullptr;
    return check ? *check : ReportObject{};
  };
  const ReportObject right = check_of(Calibrated());
  EXPECT_EQ(AsBool(Member(right, "consistent")), true);
  EXPECT_NEAR(AsNumber(Member(right, "calibrated_mm")).value_or(0.0), truth_mm, 0.001 * truth_mm);
  EXPECT_THAT(calibrate_->output, Not(HasSubstr("calibrated focal length")));

  const fs::path typed = dir_->path() / "focal_50";
  testing::CopyProject(testing::SimulatedProject("demo", 1).project_dir, typed);
  testing::ReplaceInFile(typed / "project.yaml", "focal_length_mm: 12", "focal_length_mm: 50");
  const auto result = testing::RunOmm("calibrate " + Quoted(typed));
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_THAT(result.output, HasSubstr("project.yaml's camera.focal_length_mm is 50"));
  const ReportObject wrong = check_of(typed);
  EXPECT_EQ(AsBool(Member(wrong, "consistent")), false);
  EXPECT_NEAR(AsNumber(Member(wrong, "calibrated_mm")).value_or(0.0), truth_mm, 0.001 * truth_mm);
}

// board.pitch_mm typed 10 for the caltab's 12.5: no image's plate is found
// whole, and the failure asks whether the board is the plate in calib/.
TEST_F(CalibrateCliTest, ABoardThatIsNotThePlateIsSuggested) {
  const fs::path typed = dir_->path() / "pitch_10";
  testing::CopyProject(testing::SimulatedProject("demo", 1).project_dir, typed);
  testing::ReplaceInFile(typed / "project.yaml", "pitch_mm: 12.5", "pitch_mm: 10");
  const auto result = testing::RunOmm("calibrate " + Quoted(typed));
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_THAT(result.output,
              HasSubstr("is project.yaml's board (caltab of 7 x 7 marks, pitch 10 mm) the plate "
                        "in calib/?"));
  EXPECT_FALSE(fs::exists(typed / "out"));
}

// Progress as each calibration image's plate is searched, from the first to
// the last of the demo's 20 (the log shows every tenth of them).
TEST_F(CalibrateCliTest, ReportsProgressPerCalibrationImage) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  EXPECT_THAT(calibrate_->output, HasSubstr("(1/20) plate search in calib_"));
  EXPECT_THAT(calibrate_->output, HasSubstr("(20/20) plate search in calib_"));
}

// The uncertainty map is the grid the report's worst_px summarises (same
// distance, same maximum), and report.html inlines it and the residual plot.
TEST_F(CalibrateCliTest, UncertaintyMapMatchesTheReportAndThePageInlinesIt) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const fs::path out = Calibrated() / "out";
  const Report report = ReadReportJson(out / "report.json");
  ASSERT_TRUE(report.calibration);
  const ReportValue* plot = Member(report.calibration->extra, "uncertainty_plot");
  ASSERT_NE(plot, nullptr);
  EXPECT_EQ(*plot, ReportValue("calibration/uncertainty.svg"));
  const auto& uncertainty =
      std::get<ReportObject>(Member(report.calibration->extra, "projection_uncertainty")->data());
  const double worst_px = std::get<double>(Member(uncertainty, "worst_px")->data());
  const double distance_mm = std::get<double>(Member(uncertainty, "distance_mm")->data());
  const std::string svg = testing::ReadTextFile(out / "calibration" / "uncertainty.svg");
  std::smatch title;
  ASSERT_TRUE(std::regex_search(
      svg, title, std::regex("at ([0-9]+) mm, 16x12 grid: ([0-9.]+) to ([0-9.]+) px")))
      << svg.substr(0, 400);
  EXPECT_NEAR(std::stod(title[1]), distance_mm, 0.5);
  EXPECT_NEAR(std::stod(title[3]), worst_px, 0.5e-4);  // printed to 4 decimals
  const std::string html = testing::ReadTextFile(out / "report.html");
  EXPECT_THAT(html, HasSubstr(svg.substr(0, svg.find("</text>"))));
  EXPECT_THAT(html, HasSubstr("Residuals (projected - observed) of"));
  EXPECT_THAT(html, HasSubstr("The mosaic stage has not run."));
}

TEST_F(CalibrateCliTest, Python3MrcalLoadsTheCameraModel) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const fs::path model = Calibrated() / "out" / "camera.cameramodel";
  const Eigen::Vector3d p(30.0, -20.0, 400.0);
  const MrcalReading mrcal = ReadWithPython3Mrcal(model, p);
  ASSERT_EQ(mrcal.python.exit_code, 0) << mrcal.python.output;
  const CameraModel camera = ReadCameraModel(model);
  EXPECT_THAT(mrcal.python.output, HasSubstr(camera.lens_model + " 1600\n"));
  // mrcal projects with the model it read exactly as our code does.
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  EXPECT_NEAR(mrcal.q.x(), q(0, 0), 1e-6) << mrcal.python.output;
  EXPECT_NEAR(mrcal.q.y(), q(1, 0), 1e-6) << mrcal.python.output;
}

TEST_F(CalibrateCliTest, ReuseFromAProjectCopiesTheCameraAndTheSolveRecord) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const fs::path dir = Reusing("reuse-project", Calibrated());
  fs::remove_all(dir / "calib");  // not needed
  const auto result = testing::RunOmm("calibrate " + Quoted(dir));
  ASSERT_EQ(result.exit_code, 0) << result.output;
  for (const char* file : {"camera.cameramodel", "calibration/solve.json"}) {
    EXPECT_EQ(testing::ReadTextFile(dir / "out" / file),
              testing::ReadTextFile(Calibrated() / "out" / file))
        << file;
  }
  const Report report = ReadReportJson(dir / "out" / "report.json");
  ASSERT_TRUE(report.calibration);
  EXPECT_EQ(report.calibration->images_used, 18);
  EXPECT_EQ(report.calibration->images_rejected.size(), 2u);
  const ReportValue* uncertainty = Member(report.calibration->extra, "projection_uncertainty");
  ASSERT_NE(uncertainty, nullptr);
  const auto* object = std::get_if<ReportObject>(&uncertainty->data());
  ASSERT_NE(object, nullptr);
  EXPECT_EQ(*Member(*object, "included"), ReportValue(true));
}

TEST_F(CalibrateCliTest, ReuseFromACameraModelSaysItsUncertaintyIsNotIncluded) {
  ASSERT_EQ(calibrate_->exit_code, 0) << calibrate_->output;
  const fs::path dir = Reusing("reuse-model", Calibrated() / "out" / "camera.cameramodel");
  const auto result = testing::RunOmm("calibrate " + Quoted(dir));
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_EQ(testing::ReadTextFile(dir / "out" / "camera.cameramodel"),
            testing::ReadTextFile(Calibrated() / "out" / "camera.cameramodel"));
  EXPECT_FALSE(fs::exists(dir / "out" / "calibration" / "solve.json"));
  const Report report = ReadReportJson(dir / "out" / "report.json");
  ASSERT_TRUE(report.calibration);
  const ReportValue* uncertainty = Member(report.calibration->extra, "projection_uncertainty");
  ASSERT_NE(uncertainty, nullptr);
  const auto* object = std::get_if<ReportObject>(&uncertainty->data());
  ASSERT_NE(object, nullptr);
  EXPECT_EQ(*Member(*object, "included"), ReportValue(false));
  EXPECT_THAT(std::get<std::string>(Member(*object, "why_not")->data()),
              HasSubstr("uncertainty is not included"));
}

TEST_F(CalibrateCliTest, ReuseFromAProjectWithoutCalibrationIsABadInput) {
  const fs::path uncalibrated = dir_->path() / "uncalibrated";
  testing::CopyProject(testing::SimulatedProject("demo", 1).project_dir, uncalibrated);
  const fs::path dir = Reusing("reuse-nothing", uncalibrated);
  const auto result = testing::RunOmm("calibrate " + Quoted(dir));
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("has no calibration"));
  EXPECT_FALSE(fs::exists(dir / "out" / "report.json"));
}

// Lens-mismatch seed 315 (20 images; the marks reached y 1038 of 1200 px):
// the chosen spline's knot field is widened (27 -> 29 deg) so that the
// whole border maps, and the log warns that the lens is extrapolated beyond
// the marks; there it follows the OPENCV8 fit, which the report records.
// python3-mrcal reads the written spline and projects as our code does,
// in the image corner the marks never reached.
TEST(CalibrateCliSplined, WidenedSplineIsWarnedAboutAndMrcalReadsItAsWritten) {
  testing::TempDir dir;
  const fs::path project = dir.path() / "lens-mismatch-315";
  testing::CopyProject(testing::SimulatedCalibration("lens-mismatch", 315).project_dir, project);
  const testing::CommandResult calibrate = testing::RunOmm("calibrate " + Quoted(project));
  ASSERT_EQ(calibrate.exit_code, 0) << calibrate.output;
  EXPECT_THAT(calibrate.output,
              HasSubstr("calibrate: the spline's knot field was widened from 27 to 29 deg"));

  const Report report = ReadReportJson(project / "out" / "report.json");
  ASSERT_TRUE(report.calibration);
  const auto& choice =
      std::get<ReportObject>(Member(report.calibration->extra, "lens_model_choice")->data());
  const ReportValue* beyond = Member(choice, "spline_beyond_marks");
  ASSERT_NE(beyond, nullptr);
  const auto& extrapolation = std::get<ReportObject>(beyond->data());
  EXPECT_EQ(*Member(extrapolation, "applied"), ReportValue(true));
  EXPECT_EQ(*Member(extrapolation, "follows"), ReportValue("LENSMODEL_OPENCV8"));

  const fs::path model = project / "out" / "camera.cameramodel";
  const CameraModel camera = ReadCameraModel(model);
  EXPECT_THAT(camera.lens_model, HasSubstr("SPLINED_STEREOGRAPHIC"));
  // A point toward the lower right corner, ~1550, 1150 px.
  const Eigen::Vector3d p(115.0, 80.0, 400.0);
  const MrcalReading mrcal = ReadWithPython3Mrcal(model, p);
  ASSERT_EQ(mrcal.python.exit_code, 0) << mrcal.python.output;
  Eigen::Matrix2Xd q;
  ASSERT_TRUE(ProjectPoints(camera, p, &q));
  EXPECT_GT(q(0, 0), 1400.0);
  EXPECT_GT(q(1, 0), 1050.0);
  EXPECT_NEAR(mrcal.q.x(), q(0, 0), 1e-6) << mrcal.python.output;
  EXPECT_NEAR(mrcal.q.y(), q(1, 0), 1e-6) << mrcal.python.output;
}

}  // namespace
}  // namespace omm
