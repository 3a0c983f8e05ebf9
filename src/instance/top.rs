//! The top tree of an instanced scene: the paper's median cut over the instances' boxes (split
//! at the midplane of the node's box along its longest axis, instances going left or right by
//! their boxes' centres; at the centre median when one side would be empty), one instance per
//! leaf, depth-first with the left child next — the node format of every other tree.

use crate::bvh::{inner_node, leaf_node};
use crate::layout::GpuNode;
use glam::Vec3;

/// One instance as the top builder sorts it.
#[derive(Clone, Copy, Debug)]
struct Item {
    min: Vec3,
    max: Vec3,
    centre: Vec3,
    instance: u32,
}

/// The top tree over `boxes` (scene-frame boxes by instance; `None`: an instance with nothing
/// to hit, left out). Leaves hold one instance each (`first` = its index); parents are not yet
/// linked. Empty when no instance has a box.
pub fn build(boxes: &[Option<(Vec3, Vec3)>]) -> Vec<GpuNode> {
    let mut items: Vec<Item> = boxes
        .iter()
        .enumerate()
        .filter_map(|(k, b)| {
            let (min, max) = (*b)?;
            Some(Item {
                min,
                max,
                centre: (min + max) * 0.5,
                instance: k as u32,
            })
        })
        .collect();
    let mut nodes = Vec::with_capacity(2 * items.len());
    if !items.is_empty() {
        node(&mut items, &mut nodes);
    }
    nodes
}

/// Appends the subtree over `items` depth-first; returns its root's index.
fn node(items: &mut [Item], nodes: &mut Vec<GpuNode>) -> u32 {
    let index = nodes.len() as u32;
    let (min, max) = items.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), it| (lo.min(it.min), hi.max(it.max)),
    );
    if items.len() == 1 {
        nodes.push(leaf_node(min, max, 1, items[0].instance));
        return index;
    }
    nodes.push(GpuNode::default());
    let extent = max - min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = (min[axis] + max[axis]) * 0.5;
    // A stable partition: the tree depends only on the instances' order and boxes.
    items.sort_by_key(|it| it.centre[axis] >= mid);
    let mut left = items.partition_point(|it| it.centre[axis] < mid);
    if left == 0 || left == items.len() {
        items.sort_by(|a, b| {
            a.centre[axis]
                .total_cmp(&b.centre[axis])
                .then(a.instance.cmp(&b.instance))
        });
        left = items.len() / 2;
    }
    let (l, r) = items.split_at_mut(left);
    node(l, nodes);
    let right = node(r, nodes);
    nodes[index as usize] = inner_node(min, max, axis, right);
    index
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_instance_with_a_box_gets_one_leaf_and_boxes_nest() {
        let boxes: Vec<Option<(Vec3, Vec3)>> = (0..37)
            .map(|k| {
                (k % 5 != 3).then(|| {
                    let p = Vec3::new((k * 7 % 11) as f32, (k % 3) as f32, (k * 13 % 5) as f32);
                    (p, p + Vec3::ONE)
                })
            })
            .collect();
        let mut nodes = build(&boxes);
        crate::bvh::link_parents(&mut nodes);
        let mut seen: Vec<u32> = nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| n.first)
            .collect();
        seen.sort();
        let want: Vec<u32> = (0..37).filter(|k| k % 5 != 3).collect();
        assert_eq!(seen, want);
        for (i, n) in nodes.iter().enumerate().skip(1) {
            let p = &nodes[n.parent() as usize];
            assert!(Vec3::from(p.min).cmple(Vec3::from(n.min)).all(), "node {i}");
            assert!(Vec3::from(p.max).cmpge(Vec3::from(n.max)).all(), "node {i}");
        }
    }
}
