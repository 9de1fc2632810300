// report.html (adapters/report_html): the page's content from hand-made
// reports with known geometry, the files it embeds, `omm report`, and the
// page as headless Chromium (Debian's `chromium`) renders it.
#include "adapters/report_html/report_html.h"

#include <cmath>
#include <filesystem>
#include <map>
#include <regex>
#include <string>

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/report_json.h"
#include "adapters/report_html/label_layout.h"
#include "tests/test_util.h"

namespace omm {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

// The mosaic of the fixture: 600 x 400 px at 0.1 mm/px.
constexpr double kGsdMm = 0.1;
const Eigen::Vector2d kOriginMm(-10.0, 20.0);
constexpr float kMosaicGray = 0.3f;  // 77 of 255 in the 8-bit preview

// Part-frame centre of mosaic pixel (col, row), by project-format.md's
// convention, which the overlay must invert.
Eigen::Vector2d PixelCentreMm(double col, double row) {
  return {kOriginMm.x() + (col + 0.5) * kGsdMm, kOriginMm.y() - (row + 0.5) * kGsdMm};
}

FeatureReport Feature(const std::string& name, const Eigen::Vector2d& centre_mm, double diameter) {
  FeatureReport f;
  f.name = name;
  f.centre_mm = centre_mm;
  f.diameter_mm = diameter;
  f.centre_sigma_mm = Eigen::Vector2d(0.0011, 0.0012);
  f.diameter_sigma_mm = 0.0021;
  return f;
}

MeasurementReport Measurement(const std::string& name, MeasurementType type, double value,
                              double sigma, double cmm) {
  MeasurementReport m;
  m.name = name;
  m.type = type;
  m.value_mm = value;
  m.sigma_mm = sigma;
  m.cmm_mm = cmm;
  m.deviation_mm = value - cmm;
  m.deviation_sigma = (value - cmm) / sigma;
  m.extra = {{"sigma_breakdown_mm",
              ReportObject{{"calibration", 0.0011}, {"registration", 0.0022}, {"edges", 0.0015}}},
             {"beyond_3_sigma", std::abs(value - cmm) > 3 * sigma}};
  return m;
}

// Every section filled, with names that need escaping.
Report FullReport() {
  Report report;
  report.project = "die <casting> & \"co\"";
  report.software_version = "0.1.0";
  report.inputs_sha256 = "0123456789abcdef";
  report.extra = {{"run_date", "2026-11-22T01:00:00Z"}};

  CalibrationReport c;
  c.lens_model = "LENSMODEL_OPENCV8";
  c.rms_px = 0.0037;
  c.images_used = 2;
  c.images_rejected = {{"calib_<02>.png", "plate not found"}};
  c.extra = {
      {"source", "calib/"},
      {"per_image",
       ReportValue::Array{
           ReportObject{
               {"image", "calib_00.png"}, {"rms_px", 0.0134}, {"inliers", 49}, {"outliers", 0}},
           ReportObject{
               {"image", "calib_01.png"}, {"rms_px", 0.0151}, {"inliers", 48}, {"outliers", 1}}}},
      {"projection_uncertainty", ReportObject{{"included", true},
                                              {"distance_mm", 406.0},
                                              {"typical_px", 0.0018},
                                              {"worst_px", 0.0267}}},
      {"residuals_plot", "calibration/residuals.svg"},
      {"uncertainty_plot", "calibration/uncertainty.svg"}};
  report.calibration = c;

  MosaicReport m;
  m.file = "mosaic.png";
  m.rms_px = 0.018;
  m.gsd_mm = kGsdMm;
  m.size_px = {600, 400};
  m.origin_mm = kOriginMm;
  m.extra = {
      {"pairs",
       ReportValue::Array{ReportObject{{"images", ReportValue::Array{"t1.png", "t2.png"}},
                                       {"predicted_overlap", 0.43},
                                       {"matched", 411},
                                       {"used", 403},
                                       {"rms_px", 0.0151},
                                       {"usable", true},
                                       {"matched_on_adjusted_scene", true},
                                       {"weight_scale", 0.4567}},
                          ReportObject{{"images", ReportValue::Array{"t1.png", "t<3>.png"}},
                                       {"predicted_overlap", 0.15},
                                       {"matched", 3},
                                       {"used", 0},
                                       {"rms_px", 0.0},
                                       {"usable", false}}}},
      {"tiles", ReportValue::Array{ReportObject{
                    {"image", "t1.png"},
                    {"commanded_mm", ReportValue::Array{67.5, -50.5}},
                    {"adjusted_minus_commanded_mm", ReportValue::Array{-0.01483, 0.00123}},
                    {"held_by_prior", false},
                    {"exposure_gain", 0.9553},
                    {"saturated_fraction", 0.0312}}}},
      {"tiles_held_by_prior",
       ReportValue::Array{ReportObject{{"image", "t<3>.png"}, {"why", "no good matches"}}}},
      {"table_sigma_check", ReportObject{{"stated_mm", 0.005},
                                         {"estimated_mm", 0.0169},
                                         {"redundancy", 13.9},
                                         {"consistent", false},
                                         {"used_mm", 0.0169}}},
      {"working_distance_check", ReportObject{{"part_mm", 1181.4},
                                              {"calibration_min_mm", 340.2},
                                              {"calibration_max_mm", 471.8},
                                              {"max_ratio", 2.0},
                                              {"consistent", false}}},
      {"table_priors_left_out",
       ReportValue::Array{
           ReportObject{{"image", "t2.png"},
                        {"adjusted_minus_commanded_mm", ReportValue::Array{-0.3012, 0.0046}},
                        {"w2", 182.31},
                        {"bound", 18.2}}}},
      {"hole_ties",
       ReportObject{{"brief", "1 hole seen whole by two tiles or more tie them; 1 dropped"},
                    {"ties", ReportValue::Array{ReportObject{
                                 {"feature", "hole_A"},
                                 {"images", ReportValue::Array{"t1.png", "t2.png"}},
                                 {"rms_px", 0.0043}}}},
                    {"dropped", ReportValue::Array{"<hole_B>"}}}},
      {"overlap_ties",
       ReportObject{{"brief", "1 of 2 overlaps of held or weakly tied tiles aligned directly"},
                    {"ties",
                     ReportValue::Array{
                         ReportObject{{"images", ReportValue::Array{"t1.png", "t<3>.png"}},
                                      {"used", true},
                                      {"pixels", 512000},
                                      {"shift_px", ReportValue::Array{0.1234, -0.05}},
                                      {"sigma_px", ReportValue::Array{0.2, 0.011}},
                                      {"rms_px", 0.021}},
                         ReportObject{{"images", ReportValue::Array{"t2.png", "t<3>.png"}},
                                      {"used", false},
                                      {"pixels", 900},
                                      {"shift_px", ReportValue::Array{0.0, 0.0}},
                                      {"sigma_px", ReportValue::Array{0.0, 0.0}},
                                      {"why", "too few pixels seen by both"}}}}}},
      {"exposure", ReportObject{{"brief", "gains 0.91..1.00"},
                                {"relative_sigma_before", 0.031},
                                {"relative_sigma_after", 0.002}}},
      {"scale_sigma_ppm", 5.84},
      {"plate_scale_check", ReportObject{{"brief", "plate on the part: whole in 1 tile(s)"},
                                         {"scale_minus_1_ppm", -3.21},
                                         {"sigma_ppm", 4.47}}}};
  report.mosaic = m;

  FeatureReport lost;
  lost.name = "<lost>";
  lost.error = "not found near <812, 400>";
  lost.extra = {{"expected_mosaic_px", ReportValue::Array{ReportValue(300.0), ReportValue(200.0)}}};
  report.features =
      std::vector<FeatureReport>{Feature("hole_A", PixelCentreMm(123, 45), 4.0),
                                 Feature("hole_B", PixelCentreMm(400, 250), 6.0), lost};
  MeasurementReport broken;
  broken.name = "<b>broken</b>";
  broken.error = "feature '<lost>' not found";
  report.measurements = std::vector<MeasurementReport>{
      Measurement("A_to_B", MeasurementType::kDistance, 34.4, 0.003, 34.39),      // 3.33 sigma
      Measurement("A_diameter", MeasurementType::kDiameter, 4.0, 0.002, 4.0024),  // -1.2 sigma
      broken};
  return report;
}

std::vector<MeasurementSpec> Specs() {
  return {{"A_to_B", MeasurementType::kDistance, {"hole_A", "hole_B"}},
          {"A_diameter", MeasurementType::kDiameter, {"hole_A"}},
          {"<b>broken</b>", MeasurementType::kDistance, {"hole_A", "<lost>"}}};
}

ReportHtmlInputs FullInputs() {
  ReportHtmlInputs inputs;
  inputs.mosaic_png =
      EncodePreviewPng(QuantizeImage(ImageF::Constant(400, 600, kMosaicGray), 16), 1200);
  inputs.residuals_svg = "<svg xmlns=\"http://www.w3.org/2000/svg\"><text>resid</text></svg>";
  inputs.uncertainty_svg =
      "<?xml version=\"1.0\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\"><text>unc</text></svg>";
  inputs.measurements = Specs();
  return inputs;
}

int Count(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

TEST(ReportHtml, EscapesEveryTextFromUserFiles) {
  const std::string html = ReportHtml(FullReport(), FullInputs());
  EXPECT_THAT(html,
              HasSubstr("<title>omm report: die &lt;casting&gt; &amp; &quot;co&quot;</title>"));
  EXPECT_THAT(html, HasSubstr("&lt;b&gt;broken&lt;/b&gt;"));
  EXPECT_THAT(html, HasSubstr("feature &#39;&lt;lost&gt;&#39; not found"));
  EXPECT_THAT(html, HasSubstr("calib_&lt;02&gt;.png"));
  EXPECT_THAT(html, HasSubstr("t&lt;3&gt;.png"));
  for (const char* raw : {"<casting>", "<b>broken", "<lost>", "<02>", "<3>", "<812"})
    EXPECT_THAT(html, Not(HasSubstr(raw))) << raw;
}

TEST(ReportHtml, IsSelfContained) {
  const std::string html = ReportHtml(FullReport(), FullInputs());
  // The only URL is SVG's namespace name (an identifier, never fetched).
  EXPECT_EQ(Count(html, "http"), Count(html, "http://www.w3.org/2000/svg"));
  EXPECT_EQ(Count(html, "<script"), 0);
  EXPECT_EQ(Count(html, "src="), 0);
  EXPECT_THAT(html, HasSubstr("href=\"data:image/png;base64,iVBORw0KGgo"));  // PNG signature
  EXPECT_THAT(html, Not(HasSubstr("<?xml")));  // the plot's prolog is dropped when inlined
}

TEST(ReportHtml, OverlayFollowsThePixelConvention) {
  const std::string html = ReportHtml(FullReport(), FullInputs());
  // User space = the mosaic's pixel grid: pixel (123, 45)'s centre is at
  // (123.5, 45.5); radius = diameter / 2 / gsd.
  EXPECT_THAT(html, HasSubstr("viewBox=\"0 0 600 400\""));
  EXPECT_THAT(html, HasSubstr("<circle cx=\"123.500\" cy=\"45.500\" r=\"20.000\""));
  EXPECT_THAT(html, HasSubstr("<circle cx=\"400.500\" cy=\"250.500\" r=\"30.000\""));
  EXPECT_EQ(Count(html, "<g class=\"feature\">"), 2);  // <lost> is not drawn as found ...
  EXPECT_THAT(html, HasSubstr("Not found: &lt;lost&gt;."));
  // ... but marked where it was looked for: expected_mosaic_px (300, 200).
  EXPECT_EQ(Count(html, "<g class=\"not-found\">"), 1);
  EXPECT_THAT(html, HasSubstr("<g class=\"not-found\"><circle cx=\"300.500\" cy=\"200.500\""));
  EXPECT_THAT(html, HasSubstr("&lt;lost&gt; (not found)</text>"));
  // One distance between found features, labelled with value and sigma.
  EXPECT_EQ(Count(html, "<g class=\"distance\">"), 1);
  EXPECT_THAT(html, HasSubstr("<line x1=\"123.500\" y1=\"45.500\" x2=\"400.500\" y2=\"250.500\""));
  EXPECT_THAT(html, HasSubstr(">A_to_B 34.4000 \u00b1 0.0030 mm</text>"));
}

TEST(ReportHtml, MeasurementsTableFlagsAndBreaksDown) {
  const std::string html = ReportHtml(FullReport(), FullInputs());
  EXPECT_THAT(html, HasSubstr("3 measurement(s): 2 made, 1 failed, 1 beyond 3 sigma"));
  const std::regex beyond("<tr class=\"beyond\"><td>A_to_B</td>");
  EXPECT_TRUE(std::regex_search(html, beyond));
  EXPECT_THAT(html, HasSubstr("<tr><td>A_diameter</td>"));
  EXPECT_THAT(html, HasSubstr("<tr class=\"failed\"><td>&lt;b&gt;broken&lt;/b&gt;</td>"));
  EXPECT_THAT(html, HasSubstr("calibration 0.0011, registration 0.0022, edges 0.0015"));
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">3.33</td>"));  // deviation / sigma
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">-1.20</td>"));
  // Each made measurement's largest part of sigma, counted (the failed one
  // has none).
  EXPECT_THAT(html, HasSubstr(" Largest part: registration for 2.</p>"));
  // A made measurement's error cell is empty; a failed one's says why.
  EXPECT_EQ(Count(html, "<span class=\"error\"></span>"), 0);
  EXPECT_THAT(html,
              HasSubstr("<span class=\"error\">feature &#39;&lt;lost&gt;&#39; not found</span>"));
}

// Where cmm.csv states the CMM's sigma: its column and the deviation against
// both sigmas beside omm's own, and the summary says which sigma it counts.
// Without it (above) neither column is there.
TEST(ReportHtml, TheCmmsSigmaWhereStated) {
  Report report = FullReport();
  MeasurementReport& m = report.measurements->front();
  m.cmm_sigma_mm = 0.004;
  m.deviation_combined_sigma = *m.deviation_mm / std::hypot(*m.sigma_mm, 0.004);
  m.extra.back().second = std::abs(*m.deviation_combined_sigma) > 3.0;  // beyond_3_sigma
  const std::string html = ReportHtml(report, FullInputs());
  EXPECT_THAT(html, HasSubstr("<th class=\"r\">CMM 1-sigma mm</th>"));
  EXPECT_THAT(html, HasSubstr("<th class=\"r\">deviation / both sigmas</th>"));
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">0.0040</td>"));
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">2.00</td>"));  // 0.010 against 0.003 and 0.004
  EXPECT_THAT(html, HasSubstr("0 beyond 3 sigma of the CMM value (highlighted; where cmm.csv "
                              "states the CMM's 1-sigma, of omm's and the CMM's combined)."));
  EXPECT_FALSE(std::regex_search(html, std::regex("<tr class=\"beyond\"><td>A_to_B</td>")));
  const std::string without = ReportHtml(FullReport(), FullInputs());
  EXPECT_THAT(without, Not(HasSubstr("CMM 1-sigma")));
  EXPECT_THAT(without, Not(HasSubstr("both sigmas")));
}

TEST(ReportHtml, EverySectionWhenEveryStageRan) {
  const std::string html = ReportHtml(FullReport(), FullInputs());
  for (const char* id :
       {"measurements-table", "features-table", "rejected-table", "per-image-table", "pairs-table",
        "hole-ties-table", "overlap-ties-table", "tiles-table", "held-table",
        "priors-left-out-table"}) {
    EXPECT_THAT(html, HasSubstr(std::string("<table id=\"") + id + "\">")) << id;
  }
  EXPECT_THAT(html, HasSubstr("<th>run_date</th><td>2026-11-22T01:00:00Z</td>"));
  EXPECT_THAT(
      html, HasSubstr("t&lt;3&gt;.png</td><td class=\"r\">512000</td><td class=\"r\">0.123</td>"));
  EXPECT_THAT(html, HasSubstr("no: too few pixels seen by both"));
  EXPECT_THAT(html, HasSubstr("0.0018 px typical (median over the imager), 0.0267 px worst, "
                              "at 406 mm"));
  EXPECT_THAT(html, HasSubstr("<text>resid</text>"));
  EXPECT_THAT(html, HasSubstr("<text>unc</text>"));
  EXPECT_THAT(html, HasSubstr("0.0169 mm against table.sigma_mm 0.0050 mm (13.9 dof): <b>too "
                              "large: the priors are weighed by, and the sigmas' table parts "
                              "assume, 0.0169 mm"));
  EXPECT_THAT(html, HasSubstr("1181 mm; the calibration plate's 340-472 mm: <b>far from it"));
  // adjusted - commanded in micrometres; a table position left out.
  EXPECT_THAT(html, HasSubstr("<tr><td>t2.png</td><td class=\"r\">-301.2</td><td "
                              "class=\"r\">4.6</td><td class=\"r\">182.3</td>"));
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">-14.83</td><td class=\"r\">1.23</td>"));
  // The tile's gain and its pixels at full scale, in %.
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">0.9553</td><td class=\"r\">3.1</td></tr>"));
  EXPECT_THAT(html, HasSubstr("<tr class=\"failed\"><td>t1.png</td><td>t&lt;3&gt;.png</td>"));
  EXPECT_THAT(html, HasSubstr("<td>yes (matched on the adjusted scene's prediction)</td>"));
  EXPECT_THAT(html, HasSubstr("<td class=\"r\">0.46</td>"));  // the pair's weight by its scatter
  EXPECT_THAT(html, HasSubstr("<tr><td>hole_A</td><td>t1.png, t2.png</td>"));
  EXPECT_THAT(html, HasSubstr("beyond their sigma): &lt;hole_B&gt;</p>"));
  // The mosaic's scale: its reference, the table's scale against it, sigma.
  EXPECT_THAT(html, HasSubstr("plate on the part: whole in 1 tile(s); the table's scale against "
                              "the plate -3.2 &plusmn; 4.5 ppm"));
  EXPECT_THAT(html, HasSubstr("<td>5.8 ppm</td>"));
  EXPECT_THAT(html, HasSubstr("gains 0.91..1.00"));
  EXPECT_THAT(html, Not(HasSubstr("has not run")));
}

// Without a plate on the part the report says where the scale came from.
// The report's other top-level members in the header: an object as a table
// of its members, nested ones likewise, every text escaped.
TEST(ReportHtml, TopLevelObjectsAreTablesOfTheirMembers) {
  Report report = FullReport();
  report.extra.emplace_back("archive", ReportObject{{"job", "<die> 7"},
                                                    {"cmm", ReportObject{{"probe_mm", 2.0}}},
                                                    {"reprocessed", true}});
  EXPECT_THAT(ReportHtml(report, FullInputs()),
              HasSubstr("<tr><th>archive</th><td><table class=\"facts\">\n"
                        "<tr><th>job</th><td>&lt;die&gt; 7</td></tr>\n"
                        "<tr><th>cmm</th><td><table class=\"facts\">\n"
                        "<tr><th>probe_mm</th><td>2</td></tr>\n</table>\n</td></tr>\n"
                        "<tr><th>reprocessed</th><td>yes</td></tr>\n</table>\n</td></tr>"));
}

// The measure stage's own section (report.json's `measure`) is said in words
// under the features, not dumped into the header; a member this version does
// not know is shown as it is.
TEST(ReportHtml, TheMeasureStagesFactsInWords) {
  Report report = FullReport();
  report.extra.emplace_back(
      "measure", ReportObject{{"brief", "2/3 <features> found"},
                              {"intrinsics_refined", true},
                              {"bore_prior", ReportObject{{"views_with_k", 25},
                                                          {"views_with_wall_level", 24},
                                                          {"bottom_rim_scale", 0.97769},
                                                          {"wall_contrast", 0.11994},
                                                          {"wall_contrast_sigma", 0.00086}}},
                              {"views_gsd_mm", 0.15},
                              {"seconds", 0.5596},
                              {"later_member", 3}});
  const std::string html = ReportHtml(report, FullInputs());
  const size_t section = html.find("<h3 id=\"measure-stage\">Measure stage</h3>");
  ASSERT_NE(section, std::string::npos);
  EXPECT_GT(section, html.find("<h3 id=\"features\">"));
  EXPECT_EQ(html.find("<th>measure</th>"), std::string::npos);  // not in the header
  EXPECT_EQ(html.find("bottom_rim_scale"), std::string::npos);
  const std::string facts = html.substr(section);
  EXPECT_THAT(facts, HasSubstr("<tr><th>summary</th><td>2/3 &lt;features&gt; found</td></tr>"));
  EXPECT_THAT(facts, HasSubstr("<td>refined by the mosaic's adjustment, the calibration their "
                               "prior</td>"));
  EXPECT_THAT(facts, HasSubstr("<td>bottom rim at 0.9777 of the top rim's scale, wall contrast "
                               "0.1199 &plusmn; 0.0009 (25 views gave the bottom rim's scale, 24 "
                               "the wall's contrast)</td>"));
  EXPECT_THAT(facts, HasSubstr("<td>0.15 mm/px</td>"));
  EXPECT_THAT(facts, HasSubstr("<td>0.56 s</td>"));
  EXPECT_THAT(facts, HasSubstr("<tr><th>later_member</th><td>3</td></tr>"));

  // Intrinsics held, and too few views for a prior: how many there were.
  report.extra.back().second =
      ReportObject{{"intrinsics_refined", false},
                   {"bore_prior", ReportObject{{"views_with_k", 2}, {"views_with_wall_level", 1}}}};
  const std::string held = ReportHtml(report, FullInputs());
  EXPECT_THAT(held, HasSubstr("<tr><th>intrinsics</th><td>as calibrated</td></tr>"));
  EXPECT_THAT(held, HasSubstr("<td>none: too few views (2 views gave the bottom rim's scale, 1 "
                              "the wall's contrast)</td>"));
}

TEST(ReportHtml, ScaleFromTheTableAloneIsSaid) {
  Report report = FullReport();
  for (auto& [key, value] : report.mosaic->extra) {
    if (key == "plate_scale_check")
      value = "no plate on the part: scale from the table positions alone (sigma <46> ppm)";
  }
  EXPECT_THAT(ReportHtml(report, FullInputs()),
              HasSubstr("no plate on the part: scale from the table positions alone (sigma "
                        "&lt;46&gt; ppm)"));
}

// Where the table's part is the largest of some measurements' sigma, the
// page says so, and, when no plate on the part gave the mosaic its scale,
// what would; with the plate's scale it only counts.
TEST(ReportHtml, ATableDominatedSigmaSaysWhatWouldShrinkIt) {
  Report report = FullReport();
  auto set_breakdown = [&](const ReportObject& breakdown) {
    for (auto& [key, value] : (*report.measurements)[0].extra)
      if (key == "sigma_breakdown_mm") value = breakdown;
  };
  set_breakdown({{"calibration", 0.0011}, {"table", 0.0031}, {"edges", 0.0015}});
  const std::string advice = "project.yaml's calibration plate lying flat on the part";
  std::string html = ReportHtml(report, FullInputs());
  EXPECT_THAT(html, HasSubstr(" Largest part: registration for 1, table for 1."));
  EXPECT_THAT(html, Not(HasSubstr(advice)));  // FullReport's plate gave the scale
  for (auto& [key, value] : report.mosaic->extra) {
    if (key == "plate_scale_check")
      value = "no plate on the part: scale from the table positions alone (sigma 46 ppm)";
  }
  html = ReportHtml(report, FullInputs());
  EXPECT_THAT(html, HasSubstr(advice));
  set_breakdown({{"calibration", 0.0011}, {"table", 0.0001}, {"edges", 0.0015}});
  html = ReportHtml(report, FullInputs());
  EXPECT_THAT(html, HasSubstr(" Largest part: edges for 1, registration for 1."));
  EXPECT_THAT(html, Not(HasSubstr(advice)));  // the table's part is nowhere the largest
}

// table.sigma_mm stated 5 mm for a table that scatters 0.0207 (15 dof): the
// check is one-sided, so it is consistent, and the page says how much less
// the positions scatter; at 0.03 stated it says nothing more.
TEST(ReportHtml, ATableScatteringFarLessThanStatedIsSaid) {
  for (const auto& [stated_mm, said] : {std::pair{5.0, true}, {0.03, false}}) {
    Report report = FullReport();
    for (auto& [key, value] : report.mosaic->extra) {
      if (key == "table_sigma_check") {
        value = ReportObject{{"stated_mm", stated_mm},
                             {"estimated_mm", 0.0207},
                             {"redundancy", 15.0},
                             {"consistent", true},
                             {"used_mm", stated_mm}};
      }
    }
    const std::string html = ReportHtml(report, FullInputs());
    EXPECT_THAT(html, HasSubstr(" dof): consistent")) << stated_mm;
    EXPECT_EQ(html.find("the positions scatter 241.5 times less than table.sigma_mm") !=
                  std::string::npos,
              said)
        << stated_mm;
    EXPECT_EQ(html.find("times less than table.sigma_mm") != std::string::npos, said) << stated_mm;
  }
}

// Tiles that nothing seen ties into one group: the groups are listed; one
// group is nothing to say.
TEST(ReportHtml, TileGroupsThatNothingTiesAreListed) {
  Report report = FullReport();
  using Array = ReportValue::Array;
  report.mosaic->extra.emplace_back("tile_groups",
                                    Array{Array{"t1.png", "t2.png"}, Array{"t<3>.png"}});
  EXPECT_THAT(ReportHtml(report, FullInputs()),
              HasSubstr("<tr><th>tile groups</th><td><b>2 groups that nothing seen in two of them "
                        "ties together</b>: t1.png, t2.png; t&lt;3&gt;.png. table.csv alone"));
  report.mosaic->extra.back().second = Array{Array{"t1.png", "t2.png", "t<3>.png"}};
  EXPECT_THAT(ReportHtml(report, FullInputs()), Not(HasSubstr("tile groups")));
}

TEST(ReportHtml, OnlyCalibrationRan) {
  Report report = FullReport();
  report.mosaic.reset();
  report.features.reset();
  report.measurements.reset();
  ReportHtmlInputs inputs = FullInputs();
  inputs.mosaic_png.clear();
  inputs.uncertainty_svg.clear();
  const std::string html = ReportHtml(report, inputs);
  EXPECT_THAT(html, HasSubstr("The measure stage has not run."));
  EXPECT_EQ(Count(html, "The mosaic stage has not run."), 2);  // figure and registration
  EXPECT_THAT(html, HasSubstr("No uncertainty map."));
  EXPECT_THAT(html, HasSubstr("<table id=\"per-image-table\">"));
  for (const char* gone : {"measurements-table", "features-table", "pairs-table", "<image"})
    EXPECT_THAT(html, Not(HasSubstr(gone))) << gone;
}

TEST(ReportHtml, CameraModelOnlyAndEmptyReport) {
  Report report;
  report.project = "p";
  CalibrationReport c;
  c.lens_model = "LENSMODEL_OPENCV8";
  c.extra = {
      {"source", "from camera model /x.cameramodel"},
      {"projection_uncertainty", ReportObject{{"included", false}, {"why_not", "no solve record"}}},
      {"rms_px_known", false}};
  report.calibration = c;
  std::string html = ReportHtml(report, {});
  EXPECT_THAT(html, HasSubstr("unknown (camera model file, no solve)"));
  EXPECT_THAT(html, HasSubstr("not included: no solve record"));
  EXPECT_THAT(html, Not(HasSubstr("per-image-table")));
  report.calibration.reset();
  html = ReportHtml(report, {});
  EXPECT_THAT(html, HasSubstr("The calibrate stage has not run."));
  EXPECT_THAT(html, HasSubstr("</html>"));
}

TEST(ReportHtml, MosaicSectionWithoutItsImageSaysWhy) {
  ReportHtmlInputs inputs = FullInputs();
  inputs.mosaic_png.clear();
  inputs.mosaic_missing_why = "'mosaic.png' not found";
  const std::string html = ReportHtml(FullReport(), inputs);
  EXPECT_THAT(html, HasSubstr("No mosaic image: &#39;mosaic.png&#39; not found"));
  EXPECT_THAT(html, HasSubstr("<table id=\"pairs-table\">"));  // the tables still come
}

TEST(ReportHtml, ReadsTheNamedFilesFromTheFirstDirHoldingThem) {
  const testing::TempDir dir;
  const fs::path staging = dir.path() / "staging", out = dir.path() / "out";
  fs::create_directories(staging / "calibration");
  fs::create_directories(out / "calibration");
  testing::WriteTextFile(staging / "calibration/uncertainty.svg", "<svg>new</svg>");
  testing::WriteTextFile(out / "calibration/uncertainty.svg", "<svg>old</svg>");
  testing::WriteTextFile(out / "calibration/residuals.svg", "<svg>resid</svg>");
  testing::WriteTextFile(dir.path() / "secret.svg", "<svg>secret</svg>");
  // 2400 px wide: the preview is area-averaged down to 1200 x 100.
  WriteGrayImage(out / "mosaic.png", ImageF::Constant(200, 2400, kMosaicGray), 16);
  Report report = FullReport();
  const ReportHtmlInputs inputs = ReadReportHtmlInputs(report, {staging, out}, Specs(), {});
  EXPECT_EQ(inputs.uncertainty_svg, "<svg>new</svg>");
  EXPECT_EQ(inputs.residuals_svg, "<svg>resid</svg>");
  EXPECT_EQ(inputs.measurements.size(), 3u);
  testing::WriteTextFile(dir.path() / "preview.png", inputs.mosaic_png);
  const GrayImage preview = ReadGrayImage(dir.path() / "preview.png");
  EXPECT_EQ(preview.width(), 1200);
  EXPECT_EQ(preview.height(), 100);
  EXPECT_NEAR(preview.pixels(50, 600), kMosaicGray, 0.5 / 255 + 1e-6);

  // Names that leave out/ are not followed; a missing mosaic is explained.
  report.calibration->extra = {{"residuals_plot", "../secret.svg"}};
  report.mosaic->file = "missing.png";
  const ReportHtmlInputs missing = ReadReportHtmlInputs(report, {out}, {}, {});
  EXPECT_EQ(missing.residuals_svg, "");
  EXPECT_EQ(missing.mosaic_png, "");
  EXPECT_EQ(missing.mosaic_missing_why, "'missing.png' not found");
}

// `omm report` rewrites report.json (normalised) and report.html from out/,
// with the distance lines from project.yaml; bad input exits 2.
TEST(ReportCommand, RegeneratesTheReportsFromOut) {
  const testing::TempDir dir;
  const Project project = testing::TinyProject(dir.path() / "tiny");
  testing::WriteTinyProject(project);
  const std::string command =
      testing::OmmProgram().string() + " report \"" + project.dir.string() + "\"";
  const testing::CommandResult none = testing::RunCommand(command);
  EXPECT_EQ(none.exit_code, 2);
  EXPECT_THAT(none.output, HasSubstr("no report yet"));

  const Report report = FullReport();  // hole_A, hole_B, A_to_B: the tiny project's names
  fs::create_directories(project.OutDir() / "calibration");
  WriteGrayImage(project.OutDir() / "mosaic.png", ImageF::Constant(400, 600, kMosaicGray), 16);
  testing::WriteTextFile(project.OutDir() / "report.json", ReportToJson(report) + "\n\n");
  const testing::CommandResult made = testing::RunCommand(command);
  ASSERT_EQ(made.exit_code, 0) << made.output;
  EXPECT_EQ(testing::ReadTextFile(project.OutDir() / "report.json"), ReportToJson(report));
  const std::string html = testing::ReadTextFile(project.OutDir() / "report.html");
  EXPECT_THAT(html, HasSubstr("<line x1=\"123.500\" y1=\"45.500\" x2=\"400.500\" y2=\"250.500\""));
  EXPECT_THAT(html, HasSubstr("href=\"data:image/png;base64,"));
  EXPECT_THAT(html, HasSubstr("No residual plot."));  // named in the report, not in out/

  testing::WriteTextFile(project.OutDir() / "report.json", "{\"format\": \"other/1\"}");
  EXPECT_EQ(testing::RunCommand(command).exit_code, 2);
}

// Headless Chromium's command line, its profile in `dir`; empty if it is
// not installed.
std::string ChromiumCommand(const fs::path& dir) {
  if (testing::RunCommand("command -v chromium").exit_code != 0) return "";
  return "timeout 60 chromium --headless --no-sandbox --disable-gpu "
         "--disable-background-networking "
         "--disable-component-update --no-first-run --hide-scrollbars --user-data-dir=\"" +
         (dir / "profile").string() + "\" ";
}

// The page in headless Chromium: the DOM it builds holds the expected rows
// (a parser's view of the escaping and the table structure), no console
// message, and the screenshot shows the embedded mosaic.
TEST(ReportHtmlChromium, RendersWithoutErrors) {
  const testing::TempDir dir;
  const std::string chromium = ChromiumCommand(dir.path());
  if (chromium.empty()) GTEST_SKIP() << "chromium is not installed (scripts/setup.sh installs it)";
  const fs::path page = dir.path() / "report.html";
  testing::WriteTextFile(page, ReportHtml(FullReport(), FullInputs()));
  const std::string url = "\"file://" + page.string() + "\"";
  const fs::path dom_path = dir.path() / "dom.html", log_path = dir.path() / "log.txt";
  const testing::CommandResult dump =
      testing::RunCommand(chromium + "--enable-logging=stderr --v=0 --dump-dom " + url + " >\"" +
                          dom_path.string() + "\" 2>\"" + log_path.string() + "\"");
  ASSERT_EQ(dump.exit_code, 0) << testing::ReadTextFile(log_path);
  const std::string dom = testing::ReadTextFile(dom_path);
  // Page messages are logged as "...:INFO:CONSOLE:<line>] "message", source: ...".
  EXPECT_THAT(testing::ReadTextFile(log_path), Not(HasSubstr(":CONSOLE")));

  EXPECT_THAT(dom, HasSubstr("<title>omm report: die &lt;casting&gt; &amp; \"co\"</title>"));
  EXPECT_THAT(dom, HasSubstr("<tr class=\"beyond\"><td>A_to_B</td>"));
  EXPECT_THAT(dom, HasSubstr("<tr class=\"failed\"><td>&lt;b&gt;broken&lt;/b&gt;</td>"));
  EXPECT_THAT(dom, Not(HasSubstr("<b>broken")));
  // Rows per table as built: the parser closed nothing early.
  const std::regex table("<table id=\"([a-z-]+)\">([\\s\\S]*?)</table>");
  std::map<std::string, int> rows;
  for (std::sregex_iterator it(dom.begin(), dom.end(), table), end; it != end; ++it)
    rows[(*it)[1]] = Count((*it)[2], "<tr");
  EXPECT_EQ(rows["measurements-table"], 1 + 3);
  EXPECT_EQ(rows["features-table"], 1 + 3);
  EXPECT_EQ(rows["pairs-table"], 1 + 2);
  EXPECT_EQ(rows["per-image-table"], 1 + 2);
  EXPECT_EQ(Count(dom, "<g class=\"feature\">"), 2);

  // The preview is a flat gray of 77/255: laid out at least 900 px wide in
  // a 1300 px window it covers >= 900 x 600 px; nothing else on the page has
  // that gray over more than a few text pixels.
  const fs::path shot = dir.path() / "shot.png";
  const testing::CommandResult screenshot =
      testing::RunCommand(chromium + "--window-size=1300,3000 --screenshot=\"" + shot.string() +
                          "\" " + url + " 2>/dev/null");
  ASSERT_EQ(screenshot.exit_code, 0) << screenshot.output;
  const GrayImage image = ReadGrayImage(shot);
  const float gray = std::round(kMosaicGray * 255.f) / 255.f;
  const auto mosaic_px = ((image.pixels.array() - gray).abs() <= 1.5f / 255.f).count();
  EXPECT_GT(mosaic_px, 900 * 600);
}

// The mosaic figure's labels as the browser sets them: 16 holes on a ring
// and the 8 distances across it, which all cross at the ring's centre (each
// distance label's first choice is the same place). The script measures
// each label's box in the real font (getBBox): no two overlap, and none is
// wider than TextWidthEstimate, which the layout pads by the labels' halos.
TEST(ReportHtmlChromium, MosaicLabelsDoNotOverlap) {
  const testing::TempDir dir;
  const std::string chromium = ChromiumCommand(dir.path());
  if (chromium.empty()) GTEST_SKIP() << "chromium is not installed (scripts/setup.sh installs it)";
  Report report = FullReport();
  std::vector<FeatureReport> features;
  std::vector<MeasurementReport> measurements;
  std::vector<MeasurementSpec> specs;
  for (int k = 0; k < 16; ++k) {
    const double angle = 2 * M_PI * k / 16;
    features.push_back(Feature(
        fmt::format("hole_{:02d}", k),
        PixelCentreMm(300 + 170 * std::cos(angle), 200 + 170 * std::sin(angle)), 1.0 + 0.2 * k));
  }
  for (int k = 0; k < 8; ++k) {
    const std::string name = fmt::format("dist_hole_{:02d}_hole_{:02d}", k, k + 8);
    measurements.push_back(Measurement(name, MeasurementType::kDistance, 34.0, 0.0021, 34.0));
    specs.push_back({name, MeasurementType::kDistance, {features[k].name, features[k + 8].name}});
  }
  report.features = features;
  report.measurements = measurements;
  ReportHtmlInputs inputs = FullInputs();
  inputs.measurements = specs;
  std::string page_html = ReportHtml(report, inputs);
  // The check runs in the page (a copy for the test: the report has no
  // scripts); its result is a <pre> that --dump-dom shows. Estimated widths
  // per label text at a font size of 1.
  std::string estimates = "const em = {";
  for (const FeatureReport& f : features)
    estimates += fmt::format("'{}': {},", f.name, TextWidthEstimate(f.name, 1.0));
  for (const MeasurementReport& m : measurements) {
    const std::string text =
        fmt::format("{} {:.4f} \u00b1 {:.4f} mm", m.name, *m.value_mm, *m.sigma_mm);
    estimates += fmt::format("'{}': {},", text, TextWidthEstimate(text, 1.0));
  }
  const std::string script = "<script>\n" + estimates + "};\n" + R"(
const svg = document.querySelector('svg.mosaic');
const font_size = parseFloat(svg.getAttribute('font-size'));
const texts = [...svg.querySelectorAll('text')];
const boxes = texts.map(t => t.getBBox());
let overlaps = 0, wider = 0;
for (let i = 0; i < boxes.length; ++i) {
  const a = boxes[i];
  if (!(a.width <= em[texts[i].textContent] * font_size)) ++wider;
  for (let j = 0; j < i; ++j) {
    const b = boxes[j];
    if (a.x < b.x + b.width && b.x < a.x + a.width && a.y < b.y + b.height && b.y < a.y + a.height)
      ++overlaps;
  }
}
const pre = document.createElement('pre');
pre.id = 'layout';
pre.textContent = `labels ${texts.length} overlaps ${overlaps} wider ${wider}` +
    ` (${boxes.map((b, i) => texts[i].textContent + ": " + b.width.toFixed(1) + "/" + (em[texts[i].textContent] * font_size).toFixed(1)).join(", ")})`;
document.body.appendChild(pre);
</script>)";
  page_html.insert(page_html.rfind("</body>"), script);
  const fs::path page = dir.path() / "report.html";
  testing::WriteTextFile(page, page_html);
  const fs::path dom_path = dir.path() / "dom.html";
  ASSERT_EQ(testing::RunCommand(chromium + "--dump-dom \"file://" + page.string() + "\" >\"" +
                                dom_path.string() + "\" 2>/dev/null")
                .exit_code,
            0);
  // 16 holes' names, 8 distances, and FullInputs' distance (A_to_B) whose
  // holes are not in this report: not drawn.
  EXPECT_THAT(testing::ReadTextFile(dom_path),
              HasSubstr("<pre id=\"layout\">labels 24 overlaps 0 wider 0 ("));
}

}  // namespace
}  // namespace omm
