#include "tet_mesh.h"

#include <algorithm>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace softrom {

TetMesh::TetMesh(const VecX& rest_positions, std::vector<Tet> tetrahedra)
    : num_nodes(static_cast<int>(rest_positions.size() / 3)),
      tets(std::move(tetrahedra)),
      rest(rest_positions) {
  dm_inv.resize(tets.size());
  volume.resize(tets.size());
  for (size_t e = 0; e < tets.size(); ++e) {
    const Tet& t = tets[e];
    for (int a = 0; a < 4; ++a) {
      if (t[a] < 0 || t[a] >= num_nodes) {
        std::ostringstream msg;
        msg << "tets[" << e << "] has node index " << t[a] << " out of range [0, " << num_nodes
            << ")";
        throw std::invalid_argument(msg.str());
      }
    }
    Mat3 dm;
    const Vec3 x0 = rest.segment<3>(3 * t[0]);
    for (int k = 0; k < 3; ++k) dm.col(k) = rest.segment<3>(3 * t[k + 1]) - x0;
    const double det = dm.determinant();
    // Scale-aware degeneracy test: compare against the cube of the longest edge.
    const double edge = std::max({dm.col(0).norm(), dm.col(1).norm(), dm.col(2).norm()});
    if (!(det > 1e-12 * edge * edge * edge) || !(edge > 0.0)) {
      std::ostringstream msg;
      msg << "tets[" << e << "] = [" << t[0] << ", " << t[1] << ", " << t[2] << ", " << t[3]
          << "] has " << (det > 0.0 ? "a near-zero" : "non-positive") << " rest volume "
          << det / 6.0;
      if (det > 0.0) msg << " (under 1e-12 / 6 of its longest edge cubed)";
      msg << " (tetrahedra must be positively oriented and non-degenerate)";
      throw std::invalid_argument(msg.str());
    }
    dm_inv[e] = dm.inverse();
    volume[e] = det / 6.0;
  }
  // A node no tet uses would carry zero mass and make the implicit system singular.
  std::vector<char> used(static_cast<size_t>(num_nodes), 0);
  for (const Tet& t : tets)
    for (int a = 0; a < 4; ++a) used[t[a]] = 1;
  for (int i = 0; i < num_nodes; ++i)
    if (!used[i]) {
      std::ostringstream msg;
      msg << "node " << i << " is not used by any tetrahedron (remove unreferenced nodes)";
      throw std::invalid_argument(msg.str());
    }
  // A tetrahedron listed twice (in any vertex order) would count its mass and stiffness twice
  // (Robot refuses it too; this is cpp_sim's own constructor's check).
  std::vector<std::pair<Tet, size_t>> sorted(tets.size());
  for (size_t e = 0; e < tets.size(); ++e) {
    sorted[e] = {tets[e], e};
    std::sort(sorted[e].first.begin(), sorted[e].first.end());
  }
  std::sort(sorted.begin(), sorted.end());
  for (size_t k = 1; k < sorted.size(); ++k)
    if (sorted[k].first == sorted[k - 1].first) {
      const Tet& t = tets[sorted[k - 1].second];
      std::ostringstream msg;
      msg << "tets[" << sorted[k - 1].second << "] and tets[" << sorted[k].second
          << "] are the same tetrahedron [" << t[0] << ", " << t[1] << ", " << t[2] << ", "
          << t[3] << "]: each element must be listed once";
      throw std::invalid_argument(msg.str());
    }
}

double TetMesh::total_volume() const {
  double v = 0.0;
  for (double ve : volume) v += ve;
  return v;
}

VecX TetMesh::lumped_mass(double density) const {
  VecX m = VecX::Zero(num_nodes);
  for (size_t e = 0; e < tets.size(); ++e)
    for (int a = 0; a < 4; ++a) m[tets[e][a]] += density * volume[e] / 4.0;
  return m;
}

Mat3 TetMesh::deformation_gradient(int e, const VecX& x) const {
  const Tet& t = tets[e];
  Mat3 ds;
  const Vec3 x0 = x.segment<3>(3 * t[0]);
  for (int k = 0; k < 3; ++k) ds.col(k) = x.segment<3>(3 * t[k + 1]) - x0;
  return ds * dm_inv[e];
}

}  // namespace softrom
