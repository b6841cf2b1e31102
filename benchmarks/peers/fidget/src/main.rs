//! A skeleton's voxels classified by Fidget: the peer of `benchmarks/peers.py`.
//!
//! usage: skelslice-peer-fidget SCENE X0 Y0 Z0 PIXEL LAYER_HEIGHT W H K
//!                              [--threads N] [--backend jit|vm] [--leaf N] [--top N]
//!
//! SCENE is a skelslice scene (JSON: `nodes`, `segments`, `segment_radii` or
//! `radii`, `units`). The grid's voxel (i, j, k) has its centre at
//! (X0 + i PIXEL, Y0 + j PIXEL, Z0 + k LAYER_HEIGHT), i < W, j < H, k < K (j
//! runs toward +y: only the set of centres matters here).
//!
//! The shape is the union of one round cone per segment: the union of the
//! balls swept along the segment, the radius interpolated linearly from one
//! end to the other (a capsule with spherical caps when both radii are
//! equal). Per segment, with s the position along the axis, q the distance
//! from the axis, L the length and k = (rb - ra) / L (|k| < 1):
//!
//!   f = sqrt(e^2 + q^2) - ra - k clamp(s + m q, 0, L),  m = k / sqrt(1 - k^2),
//!   e = max(min(s, -m q), s - L)
//!
//! which is min over the swept balls of (distance to the centre - radius):
//! negative exactly inside the union. (When |k| >= 1 one end ball holds the
//! other and the segment is that ball.) The scene is min over the segments,
//! as one Fidget expression (a balanced tree of `min`).
//!
//! Every voxel centre is classified by an interval octree on Fidget's public
//! evaluators: a cell (a cube of voxels, clipped to the grid) is evaluated
//! with the interval tape over the box of its voxel centres; an interval
//! wholly below zero settles the cell inside, one at or above zero outside;
//! otherwise the shape is simplified with the interval evaluation's trace
//! (the `min` branches that cannot win in the cell are dropped) and the cell
//! is split in eight, down to leaves of `--leaf` voxels a side, whose centres
//! the simplified shape's float-slice tape evaluates in bulk (inside: f < 0).
//! Cells larger than `--top` go through a queue shared by `--threads` threads
//! (0: all cores); smaller ones are recursed by the thread that took them.
//!
//! Prints one JSON line: `seconds` (classification only, after the shape and
//! its first interval tape are built), `inside` (voxel count), the grid,
//! backend, threads and counters.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use fidget::context::{Context, Node};
use fidget::eval::{Function, MathFunction, TracingEvaluator};
use fidget::shape::{Shape, ShapeBulkEval, ShapeTape, ShapeTracingEval};
use fidget::types::Interval;

type ITape<F> = ShapeTape<<<F as Function>::IntervalEval as TracingEvaluator>::Tape>;

fn fail(msg: &str) -> ! {
    eprintln!("skelslice-peer-fidget: {msg}");
    std::process::exit(2)
}

// ------------------------------------------------------------------ the scene

struct Capsule {
    a: [f64; 3],
    b: [f64; 3],
    ra: f64,
    rb: f64,
}

fn read_scene(path: &str) -> Vec<Capsule> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| fail(&format!("{path}: {e}")));
    let doc: serde_json::Value =
        serde_json::from_str(&text).unwrap_or_else(|e| fail(&format!("{path}: {e}")));
    let scale = match doc.get("units").and_then(|u| u.as_str()).unwrap_or("mm") {
        "mm" => 1.0,
        "um" => 1e-3,
        "cm" => 10.0,
        "m" => 1e3,
        "in" => 25.4,
        u => fail(&format!("{path}: unknown units {u:?}")),
    };
    let num = |v: &serde_json::Value| -> f64 {
        v.as_f64().unwrap_or_else(|| fail(&format!("{path}: not a number: {v}")))
    };
    let rows = |key: &str| -> Vec<Vec<f64>> {
        doc.get(key)
            .and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .map(|r| match r.as_array() {
                        Some(r) => r.iter().map(num).collect(),
                        None => vec![num(r)],
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let nodes = rows("nodes");
    let segments = rows("segments");
    if nodes.iter().any(|n| n.len() != 3) || segments.iter().any(|s| s.len() != 2) {
        fail(&format!("{path}: nodes must be (n, 3) and segments (m, 2)"));
    }
    let seg_radii = rows("segment_radii");
    let node_radii = rows("radii");
    let mut out = Vec::with_capacity(segments.len());
    for (e, s) in segments.iter().enumerate() {
        let (i, j) = (s[0] as usize, s[1] as usize);
        if i >= nodes.len() || j >= nodes.len() {
            fail(&format!("{path}: segment {e} names a missing node"));
        }
        let (ra, rb) = if !seg_radii.is_empty() {
            let r = &seg_radii[e];
            (r[0], r[1])
        } else if !node_radii.is_empty() {
            (node_radii[i][0], node_radii[j][0])
        } else {
            fail(&format!("{path}: no segment_radii or radii"))
        };
        let p = |n: &Vec<f64>| [n[0] * scale, n[1] * scale, n[2] * scale];
        out.push(Capsule { a: p(&nodes[i]), b: p(&nodes[j]), ra: ra * scale, rb: rb * scale });
    }
    if out.is_empty() {
        fail(&format!("{path}: no segments"));
    }
    out
}

/// `c0 + c[0] x + c[1] y + c[2] z` (terms with a zero coefficient left out)
fn linear(ctx: &mut Context, xyz: [Node; 3], c: [f64; 3], c0: f64) -> Node {
    let mut acc = ctx.constant(c0 as f32);
    for (v, k) in xyz.into_iter().zip(c) {
        if k != 0.0 {
            let t = ctx.mul(v, k as f32).unwrap();
            acc = ctx.add(acc, t).unwrap();
        }
    }
    acc
}

fn ball(ctx: &mut Context, xyz: [Node; 3], c: [f64; 3], r: f64) -> Node {
    let mut sum = None;
    for a in 0..3 {
        let mut e = [0.0; 3];
        e[a] = 1.0;
        let d = linear(ctx, xyz, e, -c[a]);
        let d2 = ctx.square(d).unwrap();
        sum = Some(match sum {
            None => d2,
            Some(s) => ctx.add(s, d2).unwrap(),
        });
    }
    let dist = ctx.sqrt(sum.unwrap()).unwrap();
    ctx.sub(dist, r as f32).unwrap()
}

/// The round cone of one segment (see the module's documentation).
fn round_cone(ctx: &mut Context, xyz: [Node; 3], c: &Capsule) -> Node {
    let v = [c.b[0] - c.a[0], c.b[1] - c.a[1], c.b[2] - c.a[2]];
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let k = if len > 0.0 { (c.rb - c.ra) / len } else { f64::INFINITY };
    if !(k.abs() < 1.0) {
        return if c.ra >= c.rb { ball(ctx, xyz, c.a, c.ra) } else { ball(ctx, xyz, c.b, c.rb) };
    }
    let u = [v[0] / len, v[1] / len, v[2] / len];
    let dot = |p: [f64; 3], q: [f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    // s = (p - a) . u; q^2 = |(p - a) x u|^2, each component a linear form of x, y, z
    let s = linear(ctx, xyz, u, -dot(c.a, u));
    let a = c.a;
    let cross = [
        ([0.0, u[2], -u[1]], -(a[1] * u[2] - a[2] * u[1])),
        ([-u[2], 0.0, u[0]], -(a[2] * u[0] - a[0] * u[2])),
        ([u[1], -u[0], 0.0], -(a[0] * u[1] - a[1] * u[0])),
    ];
    let mut q2 = None;
    for (coef, c0) in cross {
        let w = linear(ctx, xyz, coef, c0);
        let w2 = ctx.square(w).unwrap();
        q2 = Some(match q2 {
            None => w2,
            Some(t) => ctx.add(t, w2).unwrap(),
        });
    }
    let q2 = q2.unwrap();
    let s_minus_len = ctx.sub(s, len as f32).unwrap();
    let (e, radius) = if k == 0.0 {
        let lo = ctx.min(s, 0.0f32).unwrap();
        (ctx.max(lo, s_minus_len).unwrap(), None)
    } else {
        let m = k / (1.0 - k * k).sqrt();
        let q = ctx.sqrt(q2).unwrap();
        let mq = ctx.mul(q, m as f32).unwrap();
        let neg_mq = ctx.neg(mq).unwrap();
        let lo = ctx.min(s, neg_mq).unwrap();
        let e = ctx.max(lo, s_minus_len).unwrap();
        let w = ctx.add(s, mq).unwrap();
        let w = ctx.min(w, len as f32).unwrap();
        let w = ctx.max(w, 0.0f32).unwrap();
        let kw = ctx.mul(w, k as f32).unwrap();
        (e, Some(kw))
    };
    let e2 = ctx.square(e).unwrap();
    let d2 = ctx.add(e2, q2).unwrap();
    let d = ctx.sqrt(d2).unwrap();
    let f = ctx.sub(d, c.ra as f32).unwrap();
    match radius {
        None => f,
        Some(kw) => ctx.sub(f, kw).unwrap(),
    }
}

/// min over the segments, as a balanced tree
fn union(ctx: &mut Context, capsules: &[Capsule]) -> Node {
    let xyz = [ctx.x(), ctx.y(), ctx.z()];
    let mut level: Vec<Node> = capsules.iter().map(|c| round_cone(ctx, xyz, c)).collect();
    while level.len() > 1 {
        level = level
            .chunks(2)
            .map(|p| if p.len() == 2 { ctx.min(p[0], p[1]).unwrap() } else { p[0] })
            .collect();
    }
    level[0]
}

// ------------------------------------------------------------------- the grid

#[derive(Clone, Copy)]
struct Grid {
    origin: [f64; 3],
    step: [f64; 3],
    size: [usize; 3],
    /// a cell of edge `e` spans `e * aspect[a]` voxels along axis `a`: about cubic in mm
    /// (the power of two nearest to the ratio of the steps, along the finer axis)
    aspect: [usize; 3],
}

impl Grid {
    /// the centre of voxel `i` along `axis`, as f32 (both evaluators see the same values)
    fn centre(&self, axis: usize, i: usize) -> f32 {
        (self.origin[axis] + i as f64 * self.step[axis]) as f32
    }

    /// the corner of child `c` (0..8) of the cell at `lo` of edge `size`
    fn child(&self, lo: [usize; 3], size: usize, c: usize) -> [usize; 3] {
        let half = size / 2;
        let bit = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
        std::array::from_fn(|a| lo[a] + bit[a] * half * self.aspect[a])
    }
}

// ------------------------------------------------------------------ the octree

#[derive(Default)]
struct Counters {
    cells: AtomicU64,
    settled_inside: AtomicU64,
    settled_outside: AtomicU64,
    simplified: AtomicU64,
    leaves: AtomicU64,
    points: AtomicU64,
}

/// A cell waiting in the shared queue: its corner and edge (voxels), the
/// shape valid in it and that shape's interval tape.
struct Item<F: Function> {
    lo: [usize; 3],
    size: usize,
    shape: Shape<F>,
    tape: ITape<F>,
}

struct Queue<F: Function> {
    items: Mutex<(Vec<Item<F>>, usize)>, // (waiting, being worked on)
    ready: Condvar,
}

impl<F: Function> Queue<F> {
    fn push(&self, item: Item<F>) {
        self.items.lock().unwrap().0.push(item);
        self.ready.notify_one();
    }

    /// The next cell, or None once the queue is empty and no thread can add to it.
    fn pop(&self) -> Option<Item<F>> {
        let mut g = self.items.lock().unwrap();
        loop {
            if let Some(item) = g.0.pop() {
                g.1 += 1;
                return Some(item);
            }
            if g.1 == 0 {
                self.ready.notify_all();
                return None;
            }
            g = self.ready.wait(g).unwrap();
        }
    }

    fn done(&self) {
        let mut g = self.items.lock().unwrap();
        g.1 -= 1;
        if g.1 == 0 && g.0.is_empty() {
            self.ready.notify_all();
        }
    }
}

enum Verdict<F: Function> {
    Inside(u64),
    Outside,
    /// ambiguous: the shape simplified for the cell (None: no smaller than the parent's)
    Split(Option<Shape<F>>),
}

struct Worker<'a, F: Function> {
    grid: Grid,
    leaf: usize,
    counters: &'a Counters,
    ieval: ShapeTracingEval<F::IntervalEval>,
    feval: ShapeBulkEval<F::FloatSliceEval>,
    workspace: F::Workspace,
    shape_storage: Vec<F::Storage>,
    tape_storage: Vec<F::TapeStorage>,
    xs: Vec<f32>,
    ys: Vec<f32>,
    zs: Vec<f32>,
}

impl<'a, F: Function> Worker<'a, F> {
    fn new(grid: Grid, leaf: usize, counters: &'a Counters) -> Self {
        Worker {
            grid,
            leaf,
            counters,
            ieval: Shape::<F>::new_interval_eval(),
            feval: Shape::<F>::new_float_slice_eval(),
            workspace: Default::default(),
            shape_storage: vec![],
            tape_storage: vec![],
            xs: vec![],
            ys: vec![],
            zs: vec![],
        }
    }

    /// The cell's voxel range [lo, hi) clipped to the grid; None when empty.
    fn clip(&self, lo: [usize; 3], size: usize) -> Option<[usize; 3]> {
        let mut hi = [0; 3];
        for a in 0..3 {
            hi[a] = (lo[a] + size * self.grid.aspect[a]).min(self.grid.size[a]);
            if hi[a] <= lo[a] {
                return None;
            }
        }
        Some(hi)
    }

    fn judge(&mut self, shape: &Shape<F>, tape: &ITape<F>, lo: [usize; 3], hi: [usize; 3]) -> Verdict<F> {
        self.counters.cells.fetch_add(1, Ordering::Relaxed);
        let iv = |a: usize| Interval::new(self.grid.centre(a, lo[a]), self.grid.centre(a, hi[a] - 1));
        let (x, y, z) = (iv(0), iv(1), iv(2));
        let (v, trace) = self.ieval.eval(tape, x, y, z).expect("interval evaluation");
        if !v.has_nan() && v.upper() < 0.0 {
            self.counters.settled_inside.fetch_add(1, Ordering::Relaxed);
            let n = (0..3).map(|a| (hi[a] - lo[a]) as u64).product();
            return Verdict::Inside(n);
        }
        if !v.has_nan() && v.lower() >= 0.0 {
            self.counters.settled_outside.fetch_add(1, Ordering::Relaxed);
            return Verdict::Outside;
        }
        let Some(trace) = trace else { return Verdict::Split(None) };
        let storage = self.shape_storage.pop().unwrap_or_default();
        let next = shape.simplify(trace, storage, &mut self.workspace).expect("simplify");
        if next.size() < shape.size() {
            self.counters.simplified.fetch_add(1, Ordering::Relaxed);
            Verdict::Split(Some(next))
        } else {
            self.shape_storage.extend(next.recycle());
            Verdict::Split(None)
        }
    }

    /// Inside voxels of the cell at `lo` of edge `size`, recursed on this thread.
    fn cell(&mut self, shape: &Shape<F>, tape: &ITape<F>, lo: [usize; 3], size: usize) -> u64 {
        let Some(hi) = self.clip(lo, size) else { return 0 };
        let next = match self.judge(shape, tape, lo, hi) {
            Verdict::Inside(n) => return n,
            Verdict::Outside => return 0,
            Verdict::Split(next) => next,
        };
        let sub = next.as_ref().unwrap_or(shape);
        let n = if size <= self.leaf {
            self.leaf_voxels(sub, lo, hi)
        } else {
            let own = next.as_ref().map(|s| s.interval_tape(self.tape_storage.pop().unwrap_or_default()));
            let t = own.as_ref().unwrap_or(tape);
            let mut n = 0;
            for c in 0..8 {
                n += self.cell(sub, t, self.grid.child(lo, size, c), size / 2);
            }
            if let Some(t) = own {
                self.tape_storage.extend(t.recycle());
            }
            n
        };
        if let Some(s) = next {
            self.shape_storage.extend(s.recycle());
        }
        n
    }

    fn leaf_voxels(&mut self, shape: &Shape<F>, lo: [usize; 3], hi: [usize; 3]) -> u64 {
        self.xs.clear();
        self.ys.clear();
        self.zs.clear();
        let xs: Vec<f32> = (lo[0]..hi[0]).map(|i| self.grid.centre(0, i)).collect();
        for k in lo[2]..hi[2] {
            let z = self.grid.centre(2, k);
            for j in lo[1]..hi[1] {
                let y = self.grid.centre(1, j);
                self.xs.extend_from_slice(&xs);
                self.ys.extend(std::iter::repeat_n(y, xs.len()));
                self.zs.extend(std::iter::repeat_n(z, xs.len()));
            }
        }
        let tape = shape.float_slice_tape(self.tape_storage.pop().unwrap_or_default());
        let out = self.feval.eval(&tape, &self.xs, &self.ys, &self.zs).expect("bulk evaluation");
        let n = out.iter().filter(|v| **v < 0.0).count() as u64;
        self.tape_storage.extend(tape.recycle());
        self.counters.leaves.fetch_add(1, Ordering::Relaxed);
        self.counters.points.fetch_add(self.xs.len() as u64, Ordering::Relaxed);
        n
    }

    /// Take cells from the queue until it is exhausted; a cell larger than
    /// `top` is judged and its children queued, a smaller one recursed here.
    fn run(&mut self, queue: &Queue<F>, top: usize) -> u64 {
        let mut inside = 0;
        while let Some(item) = queue.pop() {
            if item.size <= top {
                inside += self.cell(&item.shape, &item.tape, item.lo, item.size);
            } else if let Some(hi) = self.clip(item.lo, item.size) {
                match self.judge(&item.shape, &item.tape, item.lo, hi) {
                    Verdict::Inside(n) => inside += n,
                    Verdict::Outside => {}
                    Verdict::Split(next) => {
                        let (shape, tape) = match next {
                            Some(s) => {
                                let t = s.interval_tape(Default::default());
                                (s, t)
                            }
                            None => (item.shape.clone(), item.tape.clone()),
                        };
                        for c in 0..8 {
                            let lo = self.grid.child(item.lo, item.size, c);
                            queue.push(Item { lo, size: item.size / 2, shape: shape.clone(), tape: tape.clone() });
                        }
                    }
                }
            }
            queue.done();
        }
        inside
    }
}

struct Outcome {
    inside: u64,
    build_seconds: f64,
    seconds: f64,
    tape_len: usize,
}

fn classify<F: Function + MathFunction + 'static>(
    capsules: &[Capsule],
    grid: Grid,
    threads: usize,
    leaf: usize,
    top: usize,
    counters: &Counters,
) -> Outcome {
    let t0 = Instant::now();
    let mut ctx = Context::new();
    let root = union(&mut ctx, capsules);
    let shape = Shape::<F>::new(&ctx, root).unwrap_or_else(|e| fail(&format!("shape: {e}")));
    let tape = shape.interval_tape(Default::default());
    let tape_len = shape.size();
    let build_seconds = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let mut edge = leaf;
    while (0..3).any(|a| edge * grid.aspect[a] < grid.size[a]) {
        edge *= 2;
    }
    let queue = Arc::new(Queue::<F> { items: Mutex::new((vec![], 0)), ready: Condvar::new() });
    queue.push(Item { lo: [0, 0, 0], size: edge, shape, tape });
    let inside: u64 = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                let queue = queue.clone();
                scope.spawn(move || Worker::<F>::new(grid, leaf, counters).run(&queue, top))
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("worker thread")).sum()
    });
    Outcome { inside, build_seconds, seconds: t1.elapsed().as_secs_f64(), tape_len }
}

// ------------------------------------------------------------------------ main

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut pos = vec![];
    let mut opts: HashMap<&str, String> = HashMap::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--threads" | "--backend" | "--leaf" | "--top" => {
                let v = it.next().unwrap_or_else(|| fail(&format!("{a} needs a value")));
                opts.insert(&a[2..], v.clone());
            }
            "-h" | "--help" => {
                println!(
                    "usage: skelslice-peer-fidget SCENE X0 Y0 Z0 PIXEL LAYER_HEIGHT W H K \
                     [--threads N] [--backend jit|vm] [--leaf N] [--top N]"
                );
                return;
            }
            _ => pos.push(a.clone()),
        }
    }
    if pos.len() != 9 {
        fail("usage: SCENE X0 Y0 Z0 PIXEL LAYER_HEIGHT W H K [--threads N] [--backend jit|vm] [--leaf N] [--top N]");
    }
    let f = |s: &String| -> f64 { s.parse().unwrap_or_else(|_| fail(&format!("not a number: {s}"))) };
    let n = |s: &String| -> usize { s.parse().unwrap_or_else(|_| fail(&format!("not a count: {s}"))) };
    let (px, h) = (f(&pos[4]), f(&pos[5]));
    if !(px > 0.0 && h > 0.0 && px.is_finite() && h.is_finite()) {
        fail("the pixel size and layer height must be > 0");
    }
    let ratio = |r: f64| 1usize << (r.log2().round().max(0.0) as u32).min(8);
    let (xy, z) = (ratio(h / px), ratio(px / h));
    let grid = Grid {
        origin: [f(&pos[1]), f(&pos[2]), f(&pos[3])],
        step: [px, px, h],
        size: [n(&pos[6]), n(&pos[7]), n(&pos[8])],
        aspect: [xy, xy, z],
    };
    if grid.size.contains(&0) {
        fail("W, H, K must be >= 1");
    }
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let threads = match opts.get("threads").map(n) {
        None | Some(0) => cores,
        Some(t) => t,
    };
    let leaf = opts.get("leaf").map(n).unwrap_or(8);
    let top = opts.get("top").map(n).unwrap_or(64);
    if leaf == 0 || !leaf.is_power_of_two() || top < leaf || !top.is_power_of_two() {
        fail("--leaf and --top must be powers of two, --top >= --leaf");
    }
    let backend = opts.get("backend").map(String::as_str).unwrap_or("jit");
    let capsules = read_scene(&pos[0]);
    let counters = Counters::default();
    let out = match backend {
        "jit" => classify::<fidget::jit::JitFunction>(&capsules, grid, threads, leaf, top, &counters),
        "vm" => classify::<fidget::vm::VmFunction>(&capsules, grid, threads, leaf, top, &counters),
        b => fail(&format!("--backend must be jit or vm, not {b}")),
    };
    let c = |a: &AtomicU64| a.load(Ordering::Relaxed);
    let doc = serde_json::json!({
        "seconds": out.seconds,
        "inside": out.inside,
        "voxels": grid.size.iter().map(|&s| s as u64).product::<u64>(),
        "backend": backend,
        "threads": threads,
        "grid": grid.size,
        "leaf": leaf,
        "top": top,
        "segments": capsules.len(),
        "tape_len": out.tape_len,
        "build_seconds": out.build_seconds,
        "cells": c(&counters.cells),
        "settled_inside": c(&counters.settled_inside),
        "settled_outside": c(&counters.settled_outside),
        "simplified": c(&counters.simplified),
        "leaves": c(&counters.leaves),
        "points": c(&counters.points),
    });
    println!("{doc}");
}
