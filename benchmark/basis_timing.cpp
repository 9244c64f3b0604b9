// The modal basis's matrices written for another tool, and the basis timed on matrices read back:
// the C++ half of benchmark/basis_vs_eigsh.py, so both sides solve the identical K and M.
//
//   basis_timing --write DIR [--size 100] [--dimension 2]   K (free dofs) and the diagonal of M, Matrix Market
//   basis_timing --read DIR --modes 30                       one computeModalBasis on them; prints its times
//                                                            and writes the eigenvalues to DIR/ours.txt
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/spring_forces.h"

#include <unsupported/Eigen/SparseExtra>

#include <chrono>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <string>

using namespace modal_mass_spring;

namespace
{

int usage()
{
  std::cerr << "usage: basis_timing --write DIR [--size N (100)] [--dimension 2|3 (2)]\n"
               "       basis_timing --read DIR --modes R\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv)
{
  std::string write_dir, read_dir;
  int size = 100, dimension = 2, modes = 0;
  for (int i = 1; i + 1 < argc; i += 2)
  {
    const std::string option = argv[i];
    const std::string value = argv[i + 1];
    if (option == "--write")
      write_dir = value;
    else if (option == "--read")
      read_dir = value;
    else if (option == "--size")
      size = std::stoi(value);
    else if (option == "--dimension")
      dimension = std::stoi(value);
    else if (option == "--modes")
      modes = std::stoi(value);
    else
      return usage();
  }
  if (argc % 2 == 0 || write_dir.empty() == read_dir.empty())
    return usage();

  if (!write_dir.empty())
  {
    if (size < 2 || (dimension != 2 && dimension != 3))
      return usage();
    GridParams p;
    p.rows = size;
    p.cols = size;
    p.dimension = dimension;
    const Grid grid(p);
    const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
    const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass());
    if (!Eigen::saveMarket(k, write_dir + "/K.mtx") || !Eigen::saveMarketVector(mass, write_dir + "/M.mtx"))
    {
      std::cerr << "basis_timing: cannot write to " << write_dir << "\n";
      return 1;
    }
    std::cout << "free_dofs " << k.rows() << " nonzeros " << k.nonZeros() << "\n";
    return 0;
  }

  SparseMatrix k;
  Eigen::VectorXd mass;
  if (!Eigen::loadMarket(k, read_dir + "/K.mtx") || !Eigen::loadMarketVector(mass, read_dir + "/M.mtx") ||
      k.rows() != mass.size() || modes < 1)
  {
    std::cerr << "basis_timing: cannot read K.mtx and M.mtx of one size from " << read_dir << ", or no --modes\n";
    return 1;
  }
  k.makeCompressed();
  const auto wall_start = std::chrono::steady_clock::now();
  const double cpu_start = threadCpuSeconds();
  const ModalBasis basis = computeModalBasis(k, mass, modes);
  const double cpu = threadCpuSeconds() - cpu_start;
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  std::ofstream out(read_dir + "/ours.txt");
  out << std::setprecision(17);
  for (int j = 0; j < basis.eigenvalues.size(); ++j)
    out << basis.eigenvalues[j] << "\n";
  std::cout << "wall " << wall << " cpu " << cpu << " factorisation " << basis.factorization_seconds << "\n";
  return out ? 0 : 1;
}
