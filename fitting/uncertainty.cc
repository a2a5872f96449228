#include "fitting/uncertainty.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "core/error.h"
#include "fitting/camera_response.h"

namespace flamerig {
namespace {

// Neighbouring fire-pixel pairs (3 residual differences each) below which the differences do not
// give the noise level: 30 pairs.
constexpr std::int64_t kMinDifferences = 90;

// The variances of each tied voxel's T and ln n from its nodes' exact covariance: the inverse of
// the nodes' precision, which sums over voxels w w^T (x) (the voxel's block / noise2) and adds the
// prior's diagonal, taken per component of nodes that share voxels. A voxel whose nodes are a
// component alone (a ring), whose component has more than `max_nodes`, whose component's
// precision the factorisation finds not positive definite, or whose variance rounding leaves at 0
// or below gets -1 (the caller's bound instead).
void NodeCovariance(const NodeTie& tie, const FitObjective::Curvature& c, double noise2,
                    double prior_t, double prior_n, std::size_t max_nodes,
                    std::vector<double>* var_t, std::vector<double>* var_n) {
  const std::size_t na = tie.node.size();
  var_t->assign(na, -1.0);
  var_n->assign(na, -1.0);
  // Components by union-find over the nodes.
  std::vector<std::uint32_t> parent(tie.nodes);
  std::iota(parent.begin(), parent.end(), 0u);
  const auto find = [&parent](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (std::size_t a = 0; a < na; ++a)
    if (tie.weight[a][0] > 0 && tie.weight[a][1] > 0) {
      const std::uint32_t x = find(tie.node[a][0]), y = find(tie.node[a][1]);
      if (x != y) parent[std::max(x, y)] = std::min(x, y);
    }
  std::vector<std::vector<std::uint32_t>> members(tie.nodes);  // nodes per component root
  for (std::uint32_t r = 0; r < tie.nodes; ++r) members[find(r)].push_back(r);
  std::vector<std::vector<std::size_t>> voxels(tie.nodes);  // voxels per component root
  for (std::size_t a = 0; a < na; ++a)
    voxels[find(tie.weight[a][0] > 0 ? tie.node[a][0] : tie.node[a][1])].push_back(a);
  std::vector<std::size_t> local(tie.nodes, 0);  // a node's place in its component
  for (std::uint32_t root = 0; root < tie.nodes; ++root) {
    const std::vector<std::uint32_t>& nodes = members[root];
    if (nodes.size() < 2 || nodes.size() > max_nodes) continue;
    for (std::size_t i = 0; i < nodes.size(); ++i) local[nodes[i]] = i;
    const Eigen::Index m = Eigen::Index(2 * nodes.size());
    Eigen::MatrixXd h = Eigen::MatrixXd::Zero(m, m);
    for (std::size_t a : voxels[root])
      for (int k = 0; k < 2; ++k)
        for (int l = 0; l < 2; ++l) {
          const double w = tie.weight[a][k] * tie.weight[a][l] / noise2;
          if (w == 0) continue;
          const Eigen::Index i = Eigen::Index(2 * local[tie.node[a][k]]),
                             j = Eigen::Index(2 * local[tie.node[a][l]]);
          h(i, j) += w * c.tt[a];
          h(i, j + 1) += w * c.tn[a];
          h(i + 1, j) += w * c.tn[a];
          h(i + 1, j + 1) += w * c.nn[a];
        }
    for (Eigen::Index i = 0; i < m; i += 2) {
      h(i, i) += 1.0 / (prior_t * prior_t);
      h(i + 1, i + 1) += 1.0 / (prior_n * prior_n);
    }
    const Eigen::LLT<Eigen::MatrixXd> llt(h);
    if (llt.info() != Eigen::Success) continue;
    const Eigen::MatrixXd cov = llt.solve(Eigen::MatrixXd::Identity(m, m));
    if (!cov.allFinite()) continue;
    for (std::size_t a : voxels[root]) {
      double vt = 0, vn = 0;
      for (int k = 0; k < 2; ++k)
        for (int l = 0; l < 2; ++l) {
          const double w = tie.weight[a][k] * tie.weight[a][l];
          if (w == 0) continue;
          const Eigen::Index i = Eigen::Index(2 * local[tie.node[a][k]]),
                             j = Eigen::Index(2 * local[tie.node[a][l]]);
          vt += w * cov(i, j);
          vn += w * cov(i + 1, j + 1);
        }
      if (!(vt > 0 && vn > 0)) continue;  // lost to rounding: the bound instead
      (*var_t)[a] = vt;
      (*var_n)[a] = vn;
    }
  }
}

}  // namespace

bool OneBand(const std::vector<FitView>& views) {
  if (views.empty()) return false;
  for (const FitView& v : views)
    if (!v.response || v.response->channels() != 1 ||
        v.response->name() != views.front().response->name())
      return false;
  return true;
}

void UncertaintyOptions::Validate() const {
  if (!(determined_fraction > 0 && determined_fraction <= 1))
    throw InputError("uncertainty: determined_fraction must be in (0, 1]");
}

VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options,
                                     const std::vector<std::vector<std::size_t>>* groups) {
  if (!groups) return EstimateUncertainty(objective, t, n, s, options, NodeTie());
  const std::size_t na = objective.num_active();
  NodeTie tie;
  tie.nodes = groups->size();
  tie.node.assign(na, {0, 0});
  tie.weight.assign(na, {0.0, 0.0});
  for (std::size_t g = 0; g < groups->size(); ++g)
    for (std::size_t a : (*groups)[g]) {
      if (a >= na) throw InputError("uncertainty: a group names voxel " + std::to_string(a));
      if (tie.weight[a][0] > 0)
        throw InputError("uncertainty: voxel " + std::to_string(a) + " is in two groups");
      tie.node[a] = {std::uint32_t(g), std::uint32_t(g)};
      tie.weight[a] = {1.0, 0.0};
    }
  for (std::size_t a = 0; a < na; ++a)
    if (!(tie.weight[a][0] > 0))
      throw InputError("uncertainty: the groups do not cover the active voxels (voxel " +
                       std::to_string(a) + ")");
  return EstimateUncertainty(objective, t, n, s, options, tie);
}

VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options, const NodeTie& tie) {
  options.Validate();
  const auto start = std::chrono::steady_clock::now();
  FitObjective::Curvature c = objective.DataCurvature(t, n, s);
  const std::size_t na = objective.num_active();
  const bool tied = tie.nodes > 0;
  if (tied) {
    if (tie.node.size() != na || tie.weight.size() != na)
      throw InputError("uncertainty: the tie has " + std::to_string(tie.node.size()) +
                       " voxels, the fit " + std::to_string(na));
    for (std::size_t a = 0; a < na; ++a)
      for (int k = 0; k < 2; ++k)
        if (tie.node[a][k] >= tie.nodes || !(tie.weight[a][k] >= 0 && tie.weight[a][k] <= 1))
          throw InputError("uncertainty: voxel " + std::to_string(a) +
                           "'s tie names a node or a weight out of range");
    for (std::size_t a = 0; a < na; ++a)
      if (!(tie.weight[a][0] > 0 || tie.weight[a][1] > 0))
        throw InputError("uncertainty: voxel " + std::to_string(a) + " weighs no node");
  }
  // Tied voxels share their nodes' (T, ln n): a node's block is its voxels' summed, each x its
  // weight squared (a voxel that names one node twice: x the sum of its weights, squared).
  const std::size_t unknowns = tied ? tie.nodes : na;
  std::size_t used = na;                                // unknowns that some voxel depends on
  std::vector<double> tt = c.tt, tn = c.tn, nn = c.nn;  // per unknown
  if (tied) {
    tt.assign(tie.nodes, 0.0);
    tn.assign(tie.nodes, 0.0);
    nn.assign(tie.nodes, 0.0);
    std::vector<char> depended(tie.nodes, 0);
    for (std::size_t a = 0; a < na; ++a)
      for (int k = 0; k < 2; ++k) {
        const bool twice = tie.node[a][0] == tie.node[a][1];
        if (twice && k == 1) continue;
        const double w = twice ? tie.weight[a][0] + tie.weight[a][1] : tie.weight[a][k];
        const double w2 = w * w;
        if (w2 == 0) continue;
        const std::uint32_t r = tie.node[a][k];
        tt[r] += w2 * c.tt[a];
        tn[r] += w2 * c.tn[a];
        nn[r] += w2 * c.nn[a];
        depended[r] = 1;
      }
    used = std::count(depended.begin(), depended.end(), 1);
  }
  VoxelUncertainty u;
  // The residuals' level per residual (degrees of freedom: less two per unknown voxel or node, at
  // least half the residuals), and the noise from their differences between neighbouring pixels,
  // scaled by the same ratio of residuals to degrees of freedom (a fit absorbs some of the noise
  // into its unknowns, and it is missing from both alike). Too few neighbouring pairs to say: the
  // level.
  const double dof = std::max(0.5 * double(c.residuals), double(c.residuals) - 2.0 * double(used));
  u.residual_lab = dof > 0 ? std::sqrt(c.residual_sq / dof) : 0.0;
  u.sigma_lab = c.differences >= kMinDifferences && dof > 0
                    ? std::sqrt(c.difference_sq / double(c.differences) * double(c.residuals) / dof)
                    : u.residual_lab;
  const ObjectiveOptions& o = objective.options();
  u.prior_sigma_k = (o.t_max_k - o.t_min_k) / std::sqrt(12.0);
  const double prior_ln =
      std::max(1e-6, std::log(objective.n_max() / objective.n_min())) / std::sqrt(12.0);
  // A noise level of zero (a perfect fit of noise-free data) would make every voxel exact: keep
  // a floor of a hundredth of a Delta E.
  const double noise2 = std::max(u.sigma_lab * u.sigma_lab, 1e-4);
  u.one_band = OneBand(objective.views());
  // Each unknown's deviations from its 2x2 precision.
  std::vector<double> var_t(unknowns), var_n(unknowns);
  for (std::size_t r = 0; r < unknowns; ++r) {
    const double htt = tt[r] / noise2 + 1.0 / (u.prior_sigma_k * u.prior_sigma_k);
    const double hnn = nn[r] / noise2 + 1.0 / (prior_ln * prior_ln);
    const double htn = tn[r] / noise2;
    // An exact block has tn^2 <= tt nn and the prior's terms make the sum positive definite; a
    // voxel whose temperature and density columns are all but parallel (its brightness could
    // come from either) loses that to rounding only: keep the determinant at a relative 1e-12
    // there. (Until the blocks were exact the cross term was clamped at 0.99 of its bound,
    // which narrowed exactly these voxels' sigma.)
    const double det = std::max(htt * hnn - htn * htn, 1e-12 * htt * hnn);
    var_t[r] = hnn / det;
    var_n[r] = htt / det;
  }
  // A tied voxel's deviations: from its nodes' exact covariance where the nodes that share voxels
  // form a component small enough to invert densely (uncertainty.h), else sum_k w_k sigma_k.
  std::vector<double> voxel_var_t, voxel_var_n;
  if (tied && !u.one_band)  // one band: the prior's deviations everywhere (below)
    NodeCovariance(tie, c, noise2, u.prior_sigma_k, prior_ln, options.max_dense_nodes, &voxel_var_t,
                   &voxel_var_n);
  u.temperature_sigma_k.resize(na);
  u.log_density_sigma.resize(na);
  u.determined.resize(na);
  for (std::size_t a = 0; a < na; ++a) {
    double vt = var_t[tied ? 0 : a], vn = var_n[tied ? 0 : a];
    if (tied && !voxel_var_t.empty() && voxel_var_t[a] >= 0) {
      vt = voxel_var_t[a];
      vn = voxel_var_n[a];
    } else if (tied) {  // sum_k w_k sigma_k (uncertainty.h)
      double st = 0, sn = 0;
      for (int k = 0; k < 2; ++k) {
        const double w = tie.weight[a][k];
        if (w == 0) continue;
        st += w * std::sqrt(var_t[tie.node[a][k]]);
        sn += w * std::sqrt(var_n[tie.node[a][k]]);
      }
      vt = st * st;
      vn = sn * sn;
    }
    const double sigma_t = std::isfinite(vt) && !u.one_band ? std::sqrt(vt) : u.prior_sigma_k;
    const double sigma_n = std::isfinite(vn) && !u.one_band ? std::sqrt(vn) : prior_ln;
    u.temperature_sigma_k[a] = float(std::min(sigma_t, u.prior_sigma_k));
    u.log_density_sigma[a] = float(std::min(sigma_n, prior_ln));
    const bool determined = sigma_t < options.determined_fraction * u.prior_sigma_k;
    u.determined[a] = determined ? 1.0f : 0.0f;
    u.determined_count += determined;
  }
  u.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return u;
}

void StoreUncertainty(const GridGeometry& grid, const std::vector<std::uint32_t>& active,
                      const VoxelUncertainty& u, FireVolume* volume) {
  const std::size_t nv = grid.num_voxels();
  volume->temperature_sigma_k.assign(nv, 0.0f);
  volume->density_sigma.assign(nv, 0.0f);
  volume->determined.assign(nv, 0.0f);
  for (std::size_t a = 0; a < active.size() && a < u.temperature_sigma_k.size(); ++a) {
    volume->temperature_sigma_k[active[a]] = u.temperature_sigma_k[a];
    volume->density_sigma[active[a]] = u.log_density_sigma[a];
    volume->determined[active[a]] = u.determined[a];
  }
  volume->metadata_numbers["sigma_lab"] = u.sigma_lab;
  volume->metadata_numbers["residual_lab"] = u.residual_lab;
  if (u.one_band) volume->metadata_numbers["one_band"] = 1;
  volume->metadata_numbers["determined_voxels"] = double(u.determined_count);
}

}  // namespace flamerig
