//! The working set of the box solver: built from a warm start (editing the cached factor when
//! few bounds differ, refactorising otherwise) and changed one bound at a time.

use super::{BoxQp, Side, NONE};

impl BoxQp {
    /// `want` from the previous solve's working set, shifted by `shift` variables.
    #[inline(always)]
    pub(super) fn previous_working_set(&mut self, shift: usize) {
        let n = self.n;
        for i in 0..n {
            let src = if i + shift < n { i + shift } else { i };
            self.want[i] = if self.lo[i] == self.hi[i] {
                Side::Fixed
            } else {
                match self.side[src] {
                    Side::Upper if self.hi[i].is_finite() => Side::Upper,
                    Side::Lower if self.lo[i].is_finite() => Side::Lower,
                    _ => Side::Free,
                }
            };
        }
    }

    /// Appends variable `j` on `side` to the working set (and a zero multiplier).
    #[inline(always)]
    pub(super) fn add(&mut self, j: usize, side: Side) -> bool {
        let m = self.ws.len();
        let col = &self.hinv[j * self.n..(j + 1) * self.n];
        for (r, &i) in self.row.iter_mut().zip(&self.ws) {
            *r = col[i];
        }
        if !self.chol.append(&self.row[..m], col[j]) {
            return false;
        }
        self.edits += 1;
        self.ws.push(j);
        self.pos[j] = m;
        self.side[j] = side;
        self.mu.push(0.0);
        true
    }

    /// Drops position `k` of the working set (and its multiplier), keeping `y` current.
    #[inline(always)]
    pub(super) fn drop_at(&mut self, k: usize) {
        let i = self.ws.remove(k);
        self.mu.remove(k);
        self.chol.delete_rotating(k, &mut self.y);
        self.y.pop();
        self.edits += 1;
        self.pos[i] = NONE;
        self.side[i] = Side::Free;
        for (kk, &v) in self.ws.iter().enumerate().skip(k) {
            self.pos[v] = kk;
        }
    }

    /// Makes the working set `want`, editing the cached factor when few bounds differ and
    /// refactorising otherwise; multipliers start at zero.
    #[inline(always)]
    pub(super) fn set_working_set(&mut self) -> bool {
        let n = self.n;
        let target = self.want.iter().filter(|s| **s != Side::Free).count();
        // A factor edited many times is computed afresh (rounding accumulates in the updates).
        let mut edit = self.chol_valid && self.edits <= 4 * n;
        if edit {
            let drops = self
                .ws
                .iter()
                .filter(|&&i| self.want[i] == Side::Free)
                .count();
            let adds = target - (self.ws.len() - drops);
            // Each edit costs O(|W|²), a fresh factor O(|W|³/3).
            edit = 3 * (drops + adds) <= target;
        }
        self.mu.clear();
        if edit {
            for k in (0..self.ws.len()).rev() {
                let i = self.ws[k];
                if self.want[i] == Side::Free {
                    self.ws.remove(k);
                    self.chol.delete(k);
                    self.edits += 1;
                    self.pos[i] = NONE;
                    self.side[i] = Side::Free;
                }
            }
            self.mu.resize(self.ws.len(), 0.0);
            for k in 0..self.ws.len() {
                let i = self.ws[k];
                self.pos[i] = k;
                self.side[i] = self.want[i];
            }
            for j in 0..n {
                if self.want[j] != Side::Free && self.pos[j] == NONE && !self.add(j, self.want[j]) {
                    self.chol_valid = false;
                    return false;
                }
            }
            return true;
        }
        self.ws.clear();
        for i in 0..n {
            self.side[i] = self.want[i];
            self.pos[i] = NONE;
            if self.want[i] != Side::Free {
                self.pos[i] = self.ws.len();
                self.ws.push(i);
            }
        }
        self.mu.resize(self.ws.len(), 0.0);
        let (ws, hinv) = (&self.ws, &self.hinv);
        self.chol_valid = self.chol.factor(ws.len(), |a, b| hinv[ws[a] * n + ws[b]]);
        self.edits = 0;
        self.chol_valid
    }
}
