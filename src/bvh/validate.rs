//! Structural checks of a flattened tree: the invariants traversal relies on.

use super::Bvh;
use crate::layout::{KIND_INNER, MAX_LEAF_SIZE};

impl Bvh {
    /// Checks the tree's invariants and returns the first violation as a sentence:
    /// every triangle sits in exactly one leaf; links point forward and in range; each child's
    /// parent link names its parent; every child box lies inside its parent's box; each leaf box
    /// holds its triangles; every node is reachable from the root exactly once.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.nodes.len();
        if n == 0 {
            return if self.triangles.is_empty() {
                Ok(())
            } else {
                Err("triangles without nodes".into())
            };
        }
        if self.triangle_ids.len() != self.triangles.len() {
            return Err("triangle_ids and triangles differ in length".into());
        }
        let mut seen_triangle = vec![false; self.triangles.len()];
        let mut seen_node = vec![false; n];
        let mut pending = vec![0usize];
        while let Some(i) = pending.pop() {
            if std::mem::replace(&mut seen_node[i], true) {
                return Err(format!("node {i} is reached twice"));
            }
            let node = &self.nodes[i];
            let kind = node.kind();
            if (1..=MAX_LEAF_SIZE).contains(&kind) {
                let first = node.first as usize;
                let end = first + kind as usize;
                if end > self.triangles.len() {
                    return Err(format!(
                        "leaf {i} names triangles {first}..{end} past the end"
                    ));
                }
                for (t, seen) in seen_triangle.iter_mut().enumerate().take(end).skip(first) {
                    if std::mem::replace(seen, true) {
                        return Err(format!("triangle {t} is in two leaves"));
                    }
                    let tri = &self.triangles[t];
                    for v in [tri.v0, tri.v1, tri.v2] {
                        if (0..3).any(|a| v[a] < node.min[a] || v[a] > node.max[a]) {
                            return Err(format!("triangle {t} pokes out of leaf {i}'s box"));
                        }
                    }
                }
            } else if (KIND_INNER..KIND_INNER + 3).contains(&kind) {
                for child in [i + 1, node.first as usize] {
                    if child <= i || child >= n {
                        return Err(format!(
                            "node {i} links to {child}, which is not after it and in range"
                        ));
                    }
                    let c = &self.nodes[child];
                    if c.parent() as usize != i {
                        return Err(format!(
                            "node {child}'s parent link is {}, not {i}",
                            c.parent()
                        ));
                    }
                    if (0..3).any(|a| c.min[a] < node.min[a] || c.max[a] > node.max[a]) {
                        return Err(format!(
                            "node {child}'s box is not inside its parent {i}'s box"
                        ));
                    }
                    pending.push(child);
                }
            } else {
                return Err(format!("node {i} has an unknown kind {kind}"));
            }
        }
        if let Some(i) = seen_node.iter().position(|s| !s) {
            return Err(format!("node {i} is unreachable"));
        }
        if let Some(t) = seen_triangle.iter().position(|s| !s) {
            return Err(format!("triangle {t} is in no leaf"));
        }
        Ok(())
    }
}
