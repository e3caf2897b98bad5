// The error ellipsoid of a position fix: the eigen-decomposition of its 3x3 covariance (cyclic Jacobi rotations,
// Golub & Van Loan, "Matrix Computations", sec. 8.5) and the scale of a confidence region (chi-square, 3 dof).

/** Scale of the 1-sigma ellipsoid giving a 3-D confidence region: sqrt of the chi-square quantile, 3 degrees of
 *  freedom (x^T C^-1 x <= k^2 holds with that probability for a Gaussian estimate). 95 %: chi2_3 = 7.814728. */
export const CONFIDENCE = {
  sigma: { label: '1 sigma (19.9 %)', scale: 1.0 },
  p95: { label: '95 %', scale: Math.sqrt(7.814727903251178) },
};

/** Eigenvalues (descending) and unit eigenvectors (columns, a right-handed basis) of a symmetric 3x3 matrix
 *  [[a, b, c], [b, d, e], [c, e, f]], by cyclic Jacobi rotations until the off-diagonal part is below 1e-15 of
 *  the Frobenius norm. Returns {values: [l0, l1, l2], vectors: [v0, v1, v2]} with C v_k = l_k v_k. */
export function symmetricEigen3(matrix) {
  const a = matrix.map((row) => [...row]);
  const v = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]; // columns accumulate the rotations
  const norm = Math.hypot(...a.flat());
  for (let sweep = 0; sweep < 50; sweep++) {
    const off = Math.hypot(a[0][1], a[0][2], a[1][2]);
    if (off <= 1e-15 * norm || off === 0) break;
    for (const [p, q] of [[0, 1], [0, 2], [1, 2]]) {
      if (a[p][q] === 0) continue;
      // the rotation that zeroes a[p][q]: tan(2 theta) = 2 a_pq / (a_qq - a_pp), the smaller root
      const theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
      const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
      const c = 1 / Math.sqrt(t * t + 1);
      const s = t * c;
      for (let k = 0; k < 3; k++) { // A <- A J (columns p, q)
        const akp = a[k][p];
        const akq = a[k][q];
        a[k][p] = c * akp - s * akq;
        a[k][q] = s * akp + c * akq;
      }
      for (let k = 0; k < 3; k++) { // A <- J^T A (rows p, q)
        const apk = a[p][k];
        const aqk = a[q][k];
        a[p][k] = c * apk - s * aqk;
        a[q][k] = s * apk + c * aqk;
      }
      for (let k = 0; k < 3; k++) { // V <- V J
        const vkp = v[k][p];
        const vkq = v[k][q];
        v[k][p] = c * vkp - s * vkq;
        v[k][q] = s * vkp + c * vkq;
      }
    }
  }
  const order = [0, 1, 2].sort((i, j) => a[j][j] - a[i][i]);
  const values = order.map((i) => a[i][i]);
  const vectors = order.map((i) => [v[0][i], v[1][i], v[2][i]]);
  const [x, y, z] = vectors;
  const det = x[0] * (y[1] * z[2] - y[2] * z[1]) - x[1] * (y[0] * z[2] - y[2] * z[0]) + x[2] * (y[0] * z[1] - y[1] * z[0]);
  if (det < 0) vectors[2] = z.map((w) => -w); // a rotation, not a reflection: the mesh's basis must be right-handed
  return { values, vectors };
}

/** Semi-axes [m] (descending) and their directions of the ellipsoid x^T C^-1 x = scale^2 of a covariance C [m^2].
 *  Eigenvalues below zero by round-off (a singular C) count as zero. */
export function errorEllipsoid(covariance_m2, scale) {
  const { values, vectors } = symmetricEigen3(covariance_m2);
  return { axes_m: values.map((l) => scale * Math.sqrt(Math.max(l, 0))), directions: vectors };
}
