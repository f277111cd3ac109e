// The OpenCV calls spinedrr makes, behind a C interface (see src/lib.rs for the contract of each).
//
// Every function catches what OpenCV throws and returns -1 with the exception's text in `err`
// (NUL-terminated, truncated to `err_len`); nothing unwinds into Rust. Arrays are row-major and
// contiguous; the caller owns every buffer.

#include <cstddef>
#include <cstring>
#include <exception>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace {

void set_error(char *err, size_t err_len, const char *what) {
  if (err == nullptr || err_len == 0) return;
  std::strncpy(err, what, err_len - 1);
  err[err_len - 1] = '\0';
}

template <typename F>
int guarded(char *err, size_t err_len, F &&f) {
  try {
    return f();
  } catch (const cv::Exception &e) {
    set_error(err, err_len, e.what());
  } catch (const std::exception &e) {
    set_error(err, err_len, e.what());
  } catch (...) {
    set_error(err, err_len, "unknown C++ exception");
  }
  return -1;
}

// A 3×1 CV_64F column from three doubles (copied: OpenCV may write to it).
cv::Mat column3(const double *v) { return (cv::Mat_<double>(3, 1) << v[0], v[1], v[2]); }

void read3(const cv::Mat &m, double *out) {
  cv::Mat d;
  m.convertTo(d, CV_64F);
  d = d.reshape(1, 3);
  for (int i = 0; i < 3; ++i) out[i] = d.at<double>(i, 0);
}

}  // namespace

extern "C" {

typedef void (*sdcv_emit_contour)(void *ctx, const int *xy, size_t points);

int sdcv_find_contours(const unsigned char *img, int rows, int cols, int off_x, int off_y,
                       sdcv_emit_contour emit, void *ctx, char *err, size_t err_len) {
  return guarded(err, err_len, [&] {
    cv::Mat m(rows, cols, CV_8UC1, const_cast<unsigned char *>(img));
    std::vector<std::vector<cv::Point>> found;
    cv::findContours(m.clone(), found, cv::RETR_LIST, cv::CHAIN_APPROX_NONE,
                     cv::Point(off_x, off_y));
    for (const auto &c : found) {
      std::vector<int> xy;
      xy.reserve(2 * c.size());
      for (const auto &p : c) {
        xy.push_back(p.x);
        xy.push_back(p.y);
      }
      emit(ctx, xy.data(), c.size());
    }
    return 0;
  });
}

int sdcv_distance_transform(const unsigned char *img, int rows, int cols, float *out, char *err,
                            size_t err_len) {
  return guarded(err, err_len, [&] {
    cv::Mat src(rows, cols, CV_8UC1, const_cast<unsigned char *>(img));
    cv::Mat dst;
    cv::distanceTransform(src, dst, cv::DIST_L2, cv::DIST_MASK_PRECISE, CV_32F);
    if (dst.type() != CV_32F || dst.rows != rows || dst.cols != cols) {
      set_error(err, err_len, "distanceTransform returned an image of another size or type");
      return -1;
    }
    for (int r = 0; r < rows; ++r) std::memcpy(out + size_t(r) * cols, dst.ptr<float>(r), sizeof(float) * cols);
    return 0;
  });
}

int sdcv_project_points(const double *obj, size_t n, const double *rvec, const double *tvec,
                        const double *k, double *out, char *err, size_t err_len) {
  return guarded(err, err_len, [&] {
    std::vector<cv::Point3d> pts(n);
    for (size_t i = 0; i < n; ++i) pts[i] = cv::Point3d(obj[3 * i], obj[3 * i + 1], obj[3 * i + 2]);
    cv::Mat km(3, 3, CV_64F, const_cast<double *>(k));
    std::vector<cv::Point2d> proj;
    cv::projectPoints(pts, column3(rvec), column3(tvec), km.clone(), cv::noArray(), proj);
    if (proj.size() != n) {
      set_error(err, err_len, "projectPoints returned another number of points");
      return -1;
    }
    for (size_t i = 0; i < n; ++i) {
      out[2 * i] = proj[i].x;
      out[2 * i + 1] = proj[i].y;
    }
    return 0;
  });
}

// method: 0 = SOLVEPNP_ITERATIVE, 1 = SOLVEPNP_SQPNP. Returns 1 when solvePnP reports no solution.
int sdcv_solve_pnp(const double *obj, const double *img, size_t n, const double *k, int method,
                   int use_guess, double *rvec, double *tvec, char *err, size_t err_len) {
  return guarded(err, err_len, [&] {
    std::vector<cv::Point3d> o(n);
    std::vector<cv::Point2d> p(n);
    for (size_t i = 0; i < n; ++i) {
      o[i] = cv::Point3d(obj[3 * i], obj[3 * i + 1], obj[3 * i + 2]);
      p[i] = cv::Point2d(img[2 * i], img[2 * i + 1]);
    }
    int flags;
    switch (method) {
      case 0: flags = cv::SOLVEPNP_ITERATIVE; break;
      case 1: flags = cv::SOLVEPNP_SQPNP; break;
      default: set_error(err, err_len, "unknown solvePnP method"); return -1;
    }
    cv::Mat km(3, 3, CV_64F, const_cast<double *>(k));
    cv::Mat r = column3(rvec), t = column3(tvec);
    bool ok = cv::solvePnP(o, p, km.clone(), cv::noArray(), r, t, use_guess != 0, flags);
    if (!ok) return 1;
    read3(r, rvec);
    read3(t, tvec);
    return 0;
  });
}

// `counts[i]` points of image i; `obj` (x, y, z) and `img` (u, v) hold all images' points in order.
// `k` (row-major 3×3) is the guess with `use_guess`, and receives the result; the lens distortion is
// fixed at zero. rvecs and tvecs receive three doubles per image. `rms` receives OpenCV's RMS.
int sdcv_calibrate_camera(const float *obj, const float *img, const size_t *counts, size_t images,
                          int width, int height, int use_guess, int max_iterations, double eps,
                          double *k, double *rvecs, double *tvecs, double *rms, char *err,
                          size_t err_len) {
  return guarded(err, err_len, [&] {
    std::vector<std::vector<cv::Point3f>> o(images);
    std::vector<std::vector<cv::Point2f>> p(images);
    size_t at = 0;
    for (size_t i = 0; i < images; ++i) {
      for (size_t j = 0; j < counts[i]; ++j, ++at) {
        o[i].emplace_back(obj[3 * at], obj[3 * at + 1], obj[3 * at + 2]);
        p[i].emplace_back(img[2 * at], img[2 * at + 1]);
      }
    }
    int flags = cv::CALIB_FIX_K1 | cv::CALIB_FIX_K2 | cv::CALIB_FIX_K3 | cv::CALIB_FIX_K4 |
                cv::CALIB_FIX_K5 | cv::CALIB_FIX_K6 | cv::CALIB_ZERO_TANGENT_DIST;
    if (use_guess) flags |= cv::CALIB_USE_INTRINSIC_GUESS;
    cv::Mat km = cv::Mat(3, 3, CV_64F, k).clone();
    cv::Mat dist = cv::Mat::zeros(1, 5, CV_64F);
    std::vector<cv::Mat> rv, tv;
    cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, max_iterations, eps);
    *rms = cv::calibrateCamera(o, p, cv::Size(width, height), km, dist, rv, tv, flags, criteria);
    if (rv.size() != images || tv.size() != images) {
      set_error(err, err_len, "calibrateCamera returned another number of poses");
      return -1;
    }
    cv::Mat kd;
    km.convertTo(kd, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) k[3 * r + c] = kd.at<double>(r, c);
    for (size_t i = 0; i < images; ++i) {
      read3(rv[i], rvecs + 3 * i);
      read3(tv[i], tvecs + 3 * i);
    }
    return 0;
  });
}

// `p` row-major 3×4; k and r receive row-major 3×3, c the homogeneous centre (4 doubles).
int sdcv_decompose_projection_matrix(const double *p, double *k, double *r, double *c, char *err,
                                     size_t err_len) {
  return guarded(err, err_len, [&] {
    cv::Mat pm = cv::Mat(3, 4, CV_64F, const_cast<double *>(p)).clone();
    cv::Mat km, rm, cm;
    cv::decomposeProjectionMatrix(pm, km, rm, cm);
    cv::Mat kd, rd, cd;
    km.convertTo(kd, CV_64F);
    rm.convertTo(rd, CV_64F);
    cm.convertTo(cd, CV_64F);
    cd = cd.reshape(1, 4);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        k[3 * i + j] = kd.at<double>(i, j);
        r[3 * i + j] = rd.at<double>(i, j);
      }
    for (int i = 0; i < 4; ++i) c[i] = cd.at<double>(i, 0);
    return 0;
  });
}

}  // extern "C"
