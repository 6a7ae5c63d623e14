// Ceres 2.1 on robust problems, for bench/compare_robust.py: a BAL bundle adjustment or a g2o pose
// graph under a named robust kernel, printing one JSON line with the cost of every iteration.
//
// usage: ceres_robust bal PROBLEM.txt  [--loss NAME:SCALE] [--linear-solver dense_schur|sparse_schur|iterative_schur]
//                                      [--threads N] [--max-iterations N]
//        ceres_robust g2o GRAPH.g2o    [--loss NAME:SCALE] [--threads N] [--max-iterations N]
//
// NAME is huber, cauchy or dcs (dynamic covariance scaling, Agarwal et al. 2013, written here as
// a LossFunction: rho = s for s <= phi, phi (3s - phi) / (phi + s) beyond). The cost is
// 0.5 * sum rho(||r||^2), Ceres' own.
//
// The models are dynamap's, so both minimise the same function from the same start:
// - BAL: the Snavely reprojection of ../shared/bench/peers/ceres_bal.cc;
// - g2o: r = U Log(Z^-1 Xi^-1 Xj) on SE(2) (tangent [v; theta]) and SE(3) (tangent [omega; v], the
//   information matrix permuted from g2o's [t; q] order as GTSAM's readG2o does), U the upper
//   Cholesky factor of the information. SE(2) poses are (x, y, theta) with the ordinary plus;
//   SE(3) poses are a translation and an Eigen quaternion on EigenQuaternionManifold. The first
//   vertex is held constant.
// Build: g++ -O3 -march=native -std=c++17 ceres_robust.cc -o ceres_robust -I/usr/include/eigen3 -lceres -lglog -lgflags -lpthread
#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace {

class DcsLoss : public ceres::LossFunction {
 public:
  explicit DcsLoss(double phi) : phi_(phi) {}
  void Evaluate(double s, double rho[3]) const override {
    if (s <= phi_) {
      rho[0] = s; rho[1] = 1.0; rho[2] = 0.0;
      return;
    }
    const double d = phi_ + s;
    rho[0] = phi_ * (3.0 * s - phi_) / d;
    rho[1] = 4.0 * phi_ * phi_ / (d * d);
    rho[2] = -8.0 * phi_ * phi_ / (d * d * d);
  }

 private:
  double phi_;
};

// A new loss for each residual block (Ceres takes ownership of each); nullptr for none.
ceres::LossFunction* MakeLoss(const std::string& spec) {
  if (spec.empty()) return nullptr;
  const auto colon = spec.find(':');
  if (colon == std::string::npos) throw std::runtime_error("--loss wants NAME:SCALE, got " + spec);
  const std::string name = spec.substr(0, colon);
  const double scale = std::stod(spec.substr(colon + 1));
  if (name == "huber") return new ceres::HuberLoss(scale);
  if (name == "cauchy") return new ceres::CauchyLoss(scale);
  if (name == "dcs") return new DcsLoss(scale);
  throw std::runtime_error("unknown loss " + name + " (huber, cauchy or dcs)");
}

struct Reprojection {
  Reprojection(double u, double v) : u(u), v(v) {}
  template <typename T> bool operator()(const T* cam, const T* pt, T* r) const {
    T p[3];
    ceres::AngleAxisRotatePoint(cam, pt, p);
    p[0] += cam[3]; p[1] += cam[4]; p[2] += cam[5];
    const T xp = -p[0] / p[2], yp = -p[1] / p[2];
    const T r2 = xp * xp + yp * yp;
    const T d = T(1.0) + r2 * (cam[7] + cam[8] * r2);
    r[0] = cam[6] * d * xp - T(u);
    r[1] = cam[6] * d * yp - T(v);
    return true;
  }
  double u, v;
};

template <typename T> T Wrap(const T& a) {
  const T two_pi(2.0 * M_PI);
  return a - two_pi * ceres::floor((a + T(M_PI)) / two_pi);
}

// r = U Log(Z^-1 Xi^-1 Xj) on SE(2), tangent [v; theta].
struct Between2 {
  Between2(double x, double y, double th, Eigen::Matrix3d u) : zx(x), zy(y), zth(th), u(u) {}
  template <typename T> bool operator()(const T* a, const T* b, T* r) const {
    const T ca = ceres::cos(a[2]), sa = ceres::sin(a[2]);
    const T dx = b[0] - a[0], dy = b[1] - a[1];
    const T lx = ca * dx + sa * dy - T(zx), ly = -sa * dx + ca * dy - T(zy);
    const double cz = std::cos(zth), sz = std::sin(zth);
    const T ex = T(cz) * lx + T(sz) * ly, ey = T(-sz) * lx + T(cz) * ly;
    const T th = Wrap(b[2] - a[2] - T(zth));
    // V(th) = [[A, -B], [B, A]], A = sin th / th, B = (1 - cos th) / th; v = V^-1 [ex, ey].
    T A, B;
    if (ceres::abs(th) < T(1e-4)) {
      A = T(1.0) - th * th / T(6.0);
      B = th / T(2.0) - th * th * th / T(24.0);
    } else {
      const T h = ceres::sin(th / T(2.0));
      A = ceres::sin(th) / th;
      B = T(2.0) * h * h / th;
    }
    const T det = A * A + B * B;
    Eigen::Matrix<T, 3, 1> e;
    e << (A * ex + B * ey) / det, (-B * ex + A * ey) / det, th;
    Eigen::Map<Eigen::Matrix<T, 3, 1>> out(r);
    out = u.cast<T>() * e;
    return true;
  }
  double zx, zy, zth;
  Eigen::Matrix3d u;
};

// r = U Log(Z^-1 Xi^-1 Xj) on SE(3), tangent [omega; v].
struct Between3 {
  Between3(Eigen::Vector3d zt, Eigen::Quaterniond zq, Eigen::Matrix<double, 6, 6> u) : zt(zt), zq(zq), u(u) {}
  template <typename T> bool operator()(const T* pa, const T* qa, const T* pb, const T* qb, T* r) const {
    using V3 = Eigen::Matrix<T, 3, 1>;
    Eigen::Map<const V3> ta(pa), tb(pb);
    Eigen::Map<const Eigen::Quaternion<T>> q_a(qa), q_b(qb);
    const Eigen::Quaternion<T> zinv = zq.conjugate().template cast<T>();
    const Eigen::Quaternion<T> qe = zinv * q_a.conjugate() * q_b;
    const V3 te = zinv * (q_a.conjugate() * (tb - ta) - zt.template cast<T>());
    // omega from the quaternion (w >= 0 for the shortest rotation)
    T q[4] = {qe.w(), qe.x(), qe.y(), qe.z()};
    if (q[0] < T(0.0)) for (auto& x : q) x = -x;
    T w[3];
    ceres::QuaternionToAngleAxis(q, w);
    const V3 om(w[0], w[1], w[2]);
    const T th2 = om.squaredNorm();
    // V^-1 = I - 1/2 [w]x + c [w]x^2, c = (1 - th sin th / (2 (1 - cos th))) / th^2
    T c;
    if (th2 < T(1e-8)) {
      c = T(1.0 / 12.0) + th2 / T(720.0);
    } else {
      const T th = ceres::sqrt(th2);
      c = (T(1.0) - th * ceres::sin(th) / (T(2.0) * (T(1.0) - ceres::cos(th)))) / th2;
    }
    const V3 wt = om.cross(te);
    const V3 v = te - T(0.5) * wt + c * om.cross(wt);
    Eigen::Matrix<T, 6, 1> e;
    e << om, v;
    Eigen::Map<Eigen::Matrix<T, 6, 1>> out(r);
    out = u.template cast<T>() * e;
    return true;
  }
  Eigen::Vector3d zt;
  Eigen::Quaterniond zq;
  Eigen::Matrix<double, 6, 6> u;
};

template <int N> Eigen::Matrix<double, N, N> UpperSqrt(const Eigen::Matrix<double, N, N>& info) {
  Eigen::LLT<Eigen::Matrix<double, N, N>> llt(info);
  if (llt.info() != Eigen::Success) throw std::runtime_error("information matrix not positive definite");
  return llt.matrixU();
}

struct Graph {
  std::map<int, std::vector<double>> vertices;  // SE2: x y th; SE3: x y z qx qy qz qw
  bool three = false;
};

void BuildG2o(const std::string& path, const std::string& loss, ceres::Problem& problem, Graph& g) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::string line;
  struct E2 { int a, b; double x, y, th; Eigen::Matrix3d u; };
  struct E3 { int a, b; Eigen::Vector3d t; Eigen::Quaterniond q; Eigen::Matrix<double, 6, 6> u; };
  std::vector<E2> e2;
  std::vector<E3> e3;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    std::string tag;
    if (!(s >> tag)) continue;
    if (tag == "VERTEX_SE2") {
      int id; std::vector<double> v(3);
      s >> id >> v[0] >> v[1] >> v[2];
      g.vertices[id] = v;
    } else if (tag == "VERTEX_SE3:QUAT") {
      int id; std::vector<double> v(7);
      s >> id; for (auto& x : v) s >> x;
      g.vertices[id] = v; g.three = true;
    } else if (tag == "EDGE_SE2") {
      E2 e; double i[6];
      s >> e.a >> e.b >> e.x >> e.y >> e.th;
      for (auto& x : i) s >> x;
      // g2o order (x, y, th) is the tangent order [v; theta] here
      Eigen::Matrix3d m;
      m << i[0], i[1], i[2], i[1], i[3], i[4], i[2], i[4], i[5];
      e.u = UpperSqrt<3>(m);
      e2.push_back(e);
    } else if (tag == "EDGE_SE3:QUAT") {
      E3 e; double t[7], i[21];
      s >> e.a >> e.b; for (auto& x : t) s >> x; for (auto& x : i) s >> x;
      e.t = Eigen::Vector3d(t[0], t[1], t[2]);
      e.q = Eigen::Quaterniond(t[6], t[3], t[4], t[5]).normalized();
      Eigen::Matrix<double, 6, 6> m;
      for (int r = 0, k = 0; r < 6; ++r) for (int c = r; c < 6; ++c, ++k) m(r, c) = m(c, r) = i[k];
      // g2o's [t; q] information to the tangent order [omega; v]
      Eigen::Matrix<double, 6, 6> p = Eigen::Matrix<double, 6, 6>::Zero();
      p.block<3, 3>(0, 3).setIdentity(); p.block<3, 3>(3, 0).setIdentity();
      e.u = UpperSqrt<6>(p * m * p.transpose());
      e3.push_back(e);
    }
  }
  for (const auto& e : e2) {
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<Between2, 3, 3, 3>(new Between2(e.x, e.y, e.th, e.u)),
                             MakeLoss(loss), g.vertices.at(e.a).data(), g.vertices.at(e.b).data());
  }
  for (const auto& e : e3) {
    auto& a = g.vertices.at(e.a); auto& b = g.vertices.at(e.b);
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<Between3, 6, 3, 4, 3, 4>(new Between3(e.t, e.q, e.u)),
                             MakeLoss(loss), a.data(), a.data() + 3, b.data(), b.data() + 3);
  }
  for (auto& [id, v] : g.vertices) {
    if (g.three && problem.HasParameterBlock(v.data() + 3))
      problem.SetManifold(v.data() + 3, new ceres::EigenQuaternionManifold);
  }
  auto& first = g.vertices.begin()->second;
  if (problem.HasParameterBlock(first.data())) problem.SetParameterBlockConstant(first.data());
  if (g.three && problem.HasParameterBlock(first.data() + 3)) problem.SetParameterBlockConstant(first.data() + 3);
}

void BuildBal(const std::string& path, const std::string& loss, ceres::Problem& problem,
              std::vector<double>& cams, std::vector<double>& pts, int& nc, int& np, int& no) {
  FILE* f = std::fopen(path.c_str(), "r");
  if (!f) throw std::runtime_error(path + ": cannot open");
  if (std::fscanf(f, "%d %d %d", &nc, &np, &no) != 3) throw std::runtime_error(path + ": bad header");
  std::vector<int> ci(no), pi(no);
  std::vector<double> obs(2 * no);
  cams.resize(9 * nc); pts.resize(3 * np);
  for (int i = 0; i < no; ++i)
    if (std::fscanf(f, "%d %d %lf %lf", &ci[i], &pi[i], &obs[2 * i], &obs[2 * i + 1]) != 4)
      throw std::runtime_error(path + ": bad observation");
  for (auto& x : cams) if (std::fscanf(f, "%lf", &x) != 1) throw std::runtime_error(path + ": bad camera");
  for (auto& x : pts) if (std::fscanf(f, "%lf", &x) != 1) throw std::runtime_error(path + ": bad point");
  std::fclose(f);
  for (int i = 0; i < no; ++i)
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<Reprojection, 2, 9, 3>(new Reprojection(obs[2 * i], obs[2 * i + 1])),
                             MakeLoss(loss), &cams[9 * ci[i]], &pts[3 * pi[i]]);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::cerr << "usage: ceres_robust bal|g2o FILE [--loss NAME:SCALE] [--linear-solver S] [--threads N] [--max-iterations N]\n";
    return 2;
  }
  const std::string kind = argv[1], path = argv[2];
  std::string loss, solver = "dense_schur";
  int threads = 2, max_iterations = 50;
  for (int i = 3; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    if (k == "--loss") loss = argv[i + 1];
    else if (k == "--linear-solver") solver = argv[i + 1];
    else if (k == "--threads") threads = std::stoi(argv[i + 1]);
    else if (k == "--max-iterations") max_iterations = std::stoi(argv[i + 1]);
    else { std::cerr << "unknown option " << k << "\n"; return 2; }
  }
  try {
    ceres::Problem problem;
    ceres::Solver::Options opts;
    opts.max_num_iterations = max_iterations;
    opts.num_threads = threads;
    opts.function_tolerance = 1e-10; opts.gradient_tolerance = 1e-12; opts.parameter_tolerance = 1e-12;
    std::vector<double> cams, pts;
    Graph graph;
    int nc = 0, np = 0, no = 0;
    if (kind == "bal") {
      BuildBal(path, loss, problem, cams, pts, nc, np, no);
      opts.linear_solver_type = solver == "sparse_schur" ? ceres::SPARSE_SCHUR
                              : solver == "iterative_schur" ? ceres::ITERATIVE_SCHUR : ceres::DENSE_SCHUR;
      if (solver == "iterative_schur") opts.preconditioner_type = ceres::SCHUR_JACOBI;
    } else if (kind == "g2o") {
      BuildG2o(path, loss, problem, graph);
      opts.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
      solver = "sparse_normal_cholesky";
    } else {
      std::cerr << "the first argument is bal or g2o\n";
      return 2;
    }
    ceres::Solver::Summary summary;
    const auto t0 = std::chrono::steady_clock::now();
    ceres::Solve(opts, &problem, &summary);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::string costs = "[";
    for (size_t i = 0; i < summary.iterations.size(); ++i) {
      char buf[40];
      std::snprintf(buf, sizeof buf, "%s%.17g", i ? ", " : "", summary.iterations[i].cost);
      costs += buf;
    }
    costs += "]";
    std::printf("{\"solver\": \"ceres\", \"version\": \"%s\", \"kind\": \"%s\", \"problem\": \"%s\", \"loss\": \"%s\", "
                "\"linear_solver\": \"%s\", \"cost_initial\": %.17g, \"cost_final\": %.17g, \"iterations\": %d, "
                "\"seconds\": %.6f, \"threads\": %d, \"termination\": \"%s\", \"costs\": %s}\n",
                CERES_VERSION_STRING, kind.c_str(), path.c_str(), loss.c_str(), solver.c_str(), summary.initial_cost,
                summary.final_cost, (int)summary.iterations.size() - 1, seconds, threads,
                ceres::TerminationTypeToString(summary.termination_type), costs.c_str());
  } catch (const std::exception& e) {
    std::cerr << "ceres_robust: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
