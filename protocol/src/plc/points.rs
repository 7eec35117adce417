//! The position table at 0x1000 as the PLC sees it: rows come from the controllers' point
//! tables, kept in a small cache.
//!
//! The cache holds [`CACHED_ROWS`] rows for all axes together, the least recently used one
//! replaced first: enough for two FC03 of 125 registers (up to 9 rows each), so a PLC that
//! reads two axes' tables in turn does not evict one with the other, at a fraction of the
//! memory 16 rows x 16 axes would take. A row that is not cached answers
//! exception 04 while it is fetched (Q1 + 9 R4, about 70 ms at 115.2 kbit/s); the PLC asks again.
//! Memory is traded for bus reads: a PLC that cycles through every row of every axis reads
//! from the controllers each time, which costs bus time, never correctness.
//!
//! A row written by the PLC is stored with [`JobKind::StorePoint`], which compares with what
//! the controller holds before it writes, so no V5 is spent on unchanged data even when the
//! row is not cached (after a restart, say); the row reads 04 until the verified read-back is in.
//! A controller that comes (back) online may have been replaced or edited: its rows are
//! forgotten.

use super::refused::Refused;
use crate::axes::AxisMap;
use crate::engine::point_jobs::{PointData, PointReadback};
use crate::engine::{Engine, Job, JobError, JobId, JobKind, JobOutput, PointAim};
use crate::memory::{flgp, PointField};
use crate::{Acceleration, Axis, PositionNo, Pulses, Velocity};

/// Rows kept, for all axes together.
pub const CACHED_ROWS: usize = 18;

#[derive(Clone, Copy, Debug)]
struct Row {
    axis: Axis,
    point: PositionNo,
    data: PointReadback,
    /// When it was last used ([`PointCache::clock`]): the smallest goes first.
    used: u32,
}

/// A read of a row for the cache.
#[derive(Clone, Copy, Debug)]
struct Read {
    id: JobId,
    point: PositionNo,
    /// A write to the row was submitted since the read started: its result is stale.
    stale: bool,
}

/// The cache, and the table reads and writes in progress (one of each per axis).
#[derive(Clone, Copy, Debug)]
pub(super) struct PointCache {
    rows: [Option<Row>; CACHED_ROWS],
    clock: u32,
    reads: AxisMap<Option<Read>>,
    writes: AxisMap<Option<(JobId, PositionNo)>>,
}

impl PointCache {
    /// Not inlined, like the other large parts of [`Gateway::new`](super::Gateway::new): the
    /// rows' temporary (864 bytes) is then in this short frame, not in the gateway's under
    /// the engine's construction.
    #[inline(never)]
    pub(super) const fn new() -> PointCache {
        PointCache {
            rows: [None; CACHED_ROWS],
            clock: 0,
            reads: AxisMap::new(None),
            writes: AxisMap::new(None),
        }
    }

    fn slot(&self, axis: Axis, point: PositionNo) -> Option<usize> {
        self.rows
            .iter()
            .position(|r| r.is_some_and(|r| r.axis == axis && r.point == point))
    }

    /// The cached row, marked as used.
    pub(super) fn get(&mut self, axis: Axis, point: PositionNo) -> Option<PointReadback> {
        self.clock = self.clock.wrapping_add(1);
        let clock = self.clock;
        let slot = self.slot(axis, point)?;
        let row = self.rows.get_mut(slot)?.as_mut()?;
        row.used = clock;
        Some(row.data)
    }

    /// What a move to the point goes by, if its row is cached (as the controller holds it; not
    /// marked as used: a move is not a use of the table): its position, and its velocity and
    /// acceleration if its flags make them count (else the common defaults do, complete
    /// edition §7-2-2, which the gateway does not know).
    pub(super) fn aim(&self, axis: Axis, point: PositionNo) -> Option<PointAim> {
        let row = self.rows.get(self.slot(axis, point)?)?.as_ref()?;
        let field = |f| row.data.get(f);
        let units = |f| u16::try_from(field(f)).ok();
        let motion = (field(PointField::Flags) & flgp::MOTION != 0)
            .then(|| {
                let velocity = Velocity::new(units(PointField::Velocity)?)?;
                Some((
                    velocity,
                    Acceleration::new(units(PointField::Acceleration)?)?,
                ))
            })
            .flatten();
        Some(PointAim {
            position: Pulses::from_wire(field(PointField::Position)),
            motion,
        })
    }

    fn put(&mut self, axis: Axis, point: PositionNo, data: PointReadback) {
        self.clock = self.clock.wrapping_add(1);
        let row = Row {
            axis,
            point,
            data,
            used: self.clock,
        };
        let slot = self.slot(axis, point).or_else(|| {
            // A free slot, else the least recently used.
            self.rows.iter().position(Option::is_none).or_else(|| {
                let clock = self.clock;
                (0..CACHED_ROWS).max_by_key(|&i| {
                    self.rows
                        .get(i)
                        .copied()
                        .flatten()
                        .map_or(u32::MAX, |r| clock.wrapping_sub(r.used))
                })
            })
        });
        if let Some(entry) = slot.and_then(|i| self.rows.get_mut(i)) {
            *entry = Some(row);
        }
    }

    /// Forget a row (a write to it is on its way), and any read of it in flight.
    pub(super) fn forget(&mut self, axis: Axis, point: PositionNo) {
        if let Some(entry) = self.slot(axis, point).and_then(|i| self.rows.get_mut(i)) {
            *entry = None;
        }
        if let Some(read) = self.reads[axis].as_mut().filter(|r| r.point == point) {
            read.stale = true;
        }
    }

    /// Forget every row of an axis (it came back online: it may have been replaced).
    pub(super) fn forget_axis(&mut self, axis: Axis) {
        for entry in self.rows.iter_mut() {
            if entry.is_some_and(|r| r.axis == axis) {
                *entry = None;
            }
        }
        if let Some(read) = self.reads[axis].as_mut() {
            read.stale = true;
        }
    }

    /// Fetch `point` of `axis` unless a read for the axis is out already.
    pub(super) fn fetch(&mut self, axis: Axis, point: PositionNo, engine: &mut Engine) {
        if self.reads[axis].is_some() || !engine.online(axis) {
            // An axis that does not answer is not asked (its frames would take the bus from
            // the live axes at job priority).
            return;
        }
        let job = Job {
            axis,
            kind: JobKind::ReadPoint(point),
        };
        if let Ok(id) = engine.submit(job) {
            self.reads[axis] = Some(Read {
                id,
                point,
                stale: false,
            });
        }
    }

    /// Store a whole row (compare, write, verify); the row reads 04 until it is done.
    pub(super) fn store(
        &mut self,
        axis: Axis,
        point: PositionNo,
        data: PointData,
        engine: &mut Engine,
    ) -> Result<(), Refused> {
        if !engine.online(axis) {
            return Err(Refused::Offline);
        }
        let id = engine
            .submit(Job {
                axis,
                kind: JobKind::StorePoint { point, data },
            })
            .map_err(|_| Refused::QueueFull)?;
        self.forget(axis, point);
        self.writes[axis] = Some((id, point));
        Ok(())
    }

    /// A job finished: keep the row it read or stored, if it is one of the cache's.
    pub(super) fn job_done(&mut self, id: JobId, axis: Axis, result: &Result<JobOutput, JobError>) {
        let row = match result {
            Ok(JobOutput::Point(readback) | JobOutput::Unchanged(readback)) => Some(*readback),
            _ => None,
        };
        let read = self.reads[axis].filter(|r| r.id == id);
        if read.is_some() {
            self.reads[axis] = None;
        }
        let write = self.writes[axis].filter(|(w, _)| *w == id);
        if write.is_some() {
            self.writes[axis] = None;
        }
        // The row a read fetched (unless a write made it stale), or a write's verified
        // read-back (nothing if the write failed): one job is never both.
        let point = match (read, write) {
            (Some(read), _) => (!read.stale).then_some(read.point),
            (None, write) => write.map(|(_, point)| point),
        };
        if let (Some(point), Some(row)) = (point, row) {
            self.put(axis, point, row);
        }
    }
}
