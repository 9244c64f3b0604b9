// Left-looking supernodal Cholesky: the symbolic analysis walks the row subtrees of the elimination
// tree (Liu), the numeric one updates each supernode from the earlier ones whose rows reach it.
#include "supernodal_cholesky.h"
#include "solvers/huge_pages.h"

#include <Eigen/Cholesky>
#include <Eigen/OrderingMethods>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace modal_mass_spring
{
namespace
{
// Supernodes at least this wide have their triangles solved by Eigen: the hand loops are
// latency-bound there (a dependent chain of additions per row).
constexpr int kWide = 8;
}  // namespace

SupernodalCholesky::SupernodalCholesky(const Eigen::SparseMatrix<double>& a, double sigma)
  : n_(static_cast<int>(a.rows()))
{
  Eigen::AMDOrdering<int>()(a, p_inverse_);
  p_ = p_inverse_.inverse();
  // Both triangles from the lower one: the analysis reads the entries above the diagonal, the
  // factorisation those below, and they must agree.
  Eigen::SparseMatrix<double> twisted;
  twisted = a.selfadjointView<Eigen::Lower>().twistedBy(p_);
  const Eigen::SparseMatrix<double> ap = twisted.transpose();  // a transpose sorts each column's rows
  analyse(ap);
  factorise(ap, sigma);
}

// The elimination tree, the row structure of L (each row i of L is the subtree of the tree spanned
// by row i of A's lower part), the supernodes (column j + 1 joins j when it is j's parent and has one
// row fewer below it: then j's rows below are j + 1's and j + 1 itself), and each supernode's rows,
// which are those of its last column.
void SupernodalCholesky::analyse(const Eigen::SparseMatrix<double>& ap)
{
  const int* start = ap.outerIndexPtr();
  const int* row = ap.innerIndexPtr();
  // Column i's entries above the diagonal are row i's left of it (A is symmetric).
  auto leftOf = [&](int i, auto visit) {
    for (int e = start[i]; e < start[i + 1] && row[e] < i; ++e)
      visit(row[e]);
  };
  std::vector<int> parent(n_, -1), ancestor(n_, -1);
  for (int i = 0; i < n_; ++i)
    leftOf(i, [&](int k) {
      while (k != -1 && k < i)  // path compression through ancestor
      {
        const int next = ancestor[k];
        ancestor[k] = i;
        if (next == -1)
          parent[k] = i;
        k = next;
      }
    });
  std::vector<int> mark(n_);
  auto rowSubtrees = [&](auto visit) {  // visit(i, j) for each L_ij != 0, j < i, rows in order
    std::fill(mark.begin(), mark.end(), -1);
    for (int i = 0; i < n_; ++i)
    {
      mark[i] = i;
      leftOf(i, [&](int k) {
        for (int j = k; mark[j] != i; j = parent[j])
        {
          mark[j] = i;
          visit(i, j);
        }
      });
    }
  };
  std::vector<int> below(n_, 0);  // rows of L below the diagonal, per column
  rowSubtrees([&](int, int j) { ++below[j]; });

  supernode_of_.assign(n_, 0);
  std::vector<int> ending(n_, -1);  // the supernode a column ends
  std::size_t rows = 0, values = 0;
  for (int first = 0; first < n_;)
  {
    int last = first;
    while (last + 1 < n_ && parent[last] == last + 1 && below[last] == below[last + 1] + 1)
      ++last;
    Supernode s;
    s.first = first;
    s.width = last - first + 1;
    s.height = s.width + below[last];
    s.rows = static_cast<int>(rows);
    s.values = static_cast<std::ptrdiff_t>(values);
    rows += s.height;
    values += static_cast<std::size_t>(s.height) * s.width;
    std::fill(supernode_of_.begin() + first, supernode_of_.begin() + last + 1, static_cast<int>(supernodes_.size()));
    ending[last] = static_cast<int>(supernodes_.size());
    supernodes_.push_back(s);
    first = last + 1;
  }
  rows_.resize(rows);
  values_.reserve(values);
  adviseHugePages(values_.data(), values * sizeof(double));
  values_.assign(values, 0.0);
  std::vector<int> filled(supernodes_.size());
  for (std::size_t k = 0; k < supernodes_.size(); ++k)
  {
    const Supernode& s = supernodes_[k];
    for (int c = 0; c < s.width; ++c)
      rows_[s.rows + c] = s.first + c;
    filled[k] = s.rows + s.width;
  }
  rowSubtrees([&](int i, int j) {
    if (ending[j] >= 0)
      rows_[filled[ending[j]]++] = i;
  });
}

void SupernodalCholesky::factorise(const Eigen::SparseMatrix<double>& ap, double sigma)
{
  const int* start = ap.outerIndexPtr();
  const int* row = ap.innerIndexPtr();
  const double* value = ap.valuePtr();
  const int count = static_cast<int>(supernodes_.size());
  // Each factorised supernode waits in the list of the next supernode its rows reach; `next_row` is
  // where in its row list that supernode's rows start.
  std::vector<int> head(count, -1), next(count, -1), next_row(count, 0);
  std::vector<int> local(n_, 0);  // a row's position in the supernode being factorised
  int tallest = 0, widest = 0;
  for (const Supernode& s : supernodes_)
  {
    tallest = std::max(tallest, s.height);
    widest = std::max(widest, s.width);
  }
  RowMajorMatrix update(tallest, widest);  // an update's columns are some of one supernode's
  tallest_ = tallest;
  inverse_diagonal_.resize(n_);
  auto wait = [&](int k, int position) {
    const int target = supernode_of_[rows_[supernodes_[k].rows + position]];
    next_row[k] = position;
    next[k] = head[target];
    head[target] = k;
  };

  for (int k = 0; k < count; ++k)
  {
    const Supernode& s = supernodes_[k];
    const int* rows = rows_.data() + s.rows;
    Eigen::Map<RowMajorMatrix> block(values_.data() + s.values, s.height, s.width);
    for (int i = 0; i < s.height; ++i)
      local[rows[i]] = i;
    for (int c = 0; c < s.width; ++c)
    {
      const int column = s.first + c;
      for (int e = start[column]; e < start[column + 1]; ++e)
        if (row[e] >= column)
          block(local[row[e]], c) = value[e];
      block(c, c) -= sigma;
    }

    // Subtract L_d L_d^T restricted to this supernode's columns, for every earlier d reaching them.
    for (int d = head[k]; d != -1;)
    {
      const int following = next[d];
      const Supernode& sd = supernodes_[d];
      const int* drows = rows_.data() + sd.rows;
      const int first = next_row[d];
      int past = first;  // d's rows within this supernode's columns are first .. past - 1
      while (past < sd.height && drows[past] < s.first + s.width)
        ++past;
      const int height = sd.height - first, width = past - first;
      const Eigen::Map<const RowMajorMatrix> ld(values_.data() + sd.values, sd.height, sd.width);
      auto product = update.topLeftCorner(height, width);
      product.noalias() = ld.middleRows(first, height) * ld.middleRows(first, width).transpose();
      for (int b = 0; b < width; ++b)
      {
        const int column = drows[first + b] - s.first;
        for (int i = b; i < height; ++i)
          block(local[drows[first + i]], column) -= product(i, b);
      }
      if (past < sd.height)
        wait(d, past);
      d = following;
    }

    auto diagonal = block.topRows(s.width);
    Eigen::LLT<Eigen::Ref<RowMajorMatrix>> llt(diagonal);
    if (llt.info() != Eigen::Success)
    {
      info_ = Eigen::NumericalIssue;
      return;
    }
    for (int c = 0; c < s.width; ++c)
    {
      if (!std::isfinite(diagonal(c, c)))  // Eigen's LLT refuses non-positive pivots, not NaN ones
      {
        info_ = Eigen::NumericalIssue;
        return;
      }
      inverse_diagonal_[s.first + c] = 1.0 / diagonal(c, c);
    }
    if (s.height > s.width)
    {
      diagonal.triangularView<Eigen::Lower>().adjoint().solveInPlace<Eigen::OnTheRight>(
          block.bottomRows(s.height - s.width));
      wait(k, s.width);
    }
  }
  info_ = Eigen::Success;
}

void SupernodalCholesky::solveInPlace(Eigen::Ref<Eigen::VectorXd> x) const
{
  work_ = p_ * x;
  gathered_.resize(tallest_);
  double* y = work_.data();
  for (const Supernode& s : supernodes_)  // L z = y
  {
    const int w = s.width, h = s.height - s.width;
    const double* triangle = values_.data() + s.values;
    const double* below = triangle + w * w;
    const int* rows = rows_.data() + s.rows + w;
    double* ys = y + s.first;
    Eigen::Map<Eigen::VectorXd> y_s(ys, w);
    if (w >= kWide)
      Eigen::Map<const RowMajorMatrix>(triangle, w, w).triangularView<Eigen::Lower>().solveInPlace(y_s);
    else
      for (int i = 0; i < w; ++i)
      {
        double sum = ys[i];
        for (int c = 0; c < i; ++c)
          sum -= triangle[i * w + c] * ys[c];
        ys[i] = sum * inverse_diagonal_[s.first + i];
      }
    // The narrow supernodes, most of a grid's, unrolled; the rest by Eigen's vectorised products.
    if (w == 1)
      for (int k = 0; k < h; ++k)
        y[rows[k]] -= below[k] * ys[0];
    else if (w == 2)
      for (int k = 0; k < h; ++k)
        y[rows[k]] -= below[2 * k] * ys[0] + below[2 * k + 1] * ys[1];
    else
    {
      auto product = gathered_.head(h);
      product.noalias() = Eigen::Map<const RowMajorMatrix>(below, h, w) * y_s;
      for (int k = 0; k < h; ++k)
        y[rows[k]] -= product[k];
    }
  }
  for (auto s = supernodes_.rbegin(); s != supernodes_.rend(); ++s)  // L^T z = y
  {
    const int w = s->width, h = s->height - s->width;
    const double* triangle = values_.data() + s->values;
    const double* below = triangle + w * w;
    const int* rows = rows_.data() + s->rows + w;
    double* ys = y + s->first;
    Eigen::Map<Eigen::VectorXd> y_s(ys, w);
    if (w == 1)
    {
      double sum = ys[0];
      for (int k = 0; k < h; ++k)
        sum -= below[k] * y[rows[k]];
      ys[0] = sum;
    }
    else if (w == 2)
    {
      double sum0 = ys[0], sum1 = ys[1];
      for (int k = 0; k < h; ++k)
      {
        const double yk = y[rows[k]];
        sum0 -= below[2 * k] * yk;
        sum1 -= below[2 * k + 1] * yk;
      }
      ys[0] = sum0;
      ys[1] = sum1;
    }
    else
    {
      auto gathered = gathered_.head(h);
      for (int k = 0; k < h; ++k)
        gathered[k] = y[rows[k]];
      y_s.noalias() -= Eigen::Map<const RowMajorMatrix>(below, h, w).transpose() * gathered;
    }
    if (w >= kWide)
      Eigen::Map<const RowMajorMatrix>(triangle, w, w).transpose().triangularView<Eigen::Upper>().solveInPlace(y_s);
    else
      for (int i = w - 1; i >= 0; --i)
      {
        ys[i] *= inverse_diagonal_[s->first + i];
        for (int c = 0; c < i; ++c)
          ys[c] -= triangle[i * w + c] * ys[i];
      }
  }
  x = p_inverse_ * work_;
}

}  // namespace modal_mass_spring
