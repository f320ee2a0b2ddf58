; Parking: cars in a street of curbs, at most two per curb, one parked at
; the curb and one double-parked beside it. A car can move only when no car
; is double-parked beside it, to a free curb or beside a car parked at a
; curb. Every move costs 1. The goal is an arrangement of the cars.
(define (domain parking)
  (:requirements :strips :typing :action-costs)
  (:types car curb)
  (:predicates
    (at-curb ?car - car)
    (at-curb-num ?car - car ?curb - curb)
    (behind-car ?car ?front-car - car)
    (car-clear ?car - car)
    (curb-clear ?curb - curb))
  (:functions (total-cost) - number)

  (:action move-curb-to-curb
    :parameters (?car - car ?from ?to - curb)
    :precondition (and (car-clear ?car) (curb-clear ?to) (at-curb-num ?car ?from))
    :effect (and (not (curb-clear ?to)) (curb-clear ?from)
                 (at-curb-num ?car ?to) (not (at-curb-num ?car ?from))
                 (increase (total-cost) 1)))

  (:action move-curb-to-car
    :parameters (?car - car ?from - curb ?front - car)
    :precondition (and (car-clear ?car) (car-clear ?front) (at-curb-num ?car ?from)
                       (at-curb ?front))
    :effect (and (not (car-clear ?front)) (curb-clear ?from) (behind-car ?car ?front)
                 (not (at-curb-num ?car ?from)) (not (at-curb ?car))
                 (increase (total-cost) 1)))

  (:action move-car-to-curb
    :parameters (?car ?front - car ?to - curb)
    :precondition (and (car-clear ?car) (curb-clear ?to) (behind-car ?car ?front))
    :effect (and (not (curb-clear ?to)) (car-clear ?front) (at-curb-num ?car ?to)
                 (not (behind-car ?car ?front)) (at-curb ?car)
                 (increase (total-cost) 1)))

  (:action move-car-to-car
    :parameters (?car ?from ?front - car)
    :precondition (and (car-clear ?car) (car-clear ?front) (behind-car ?car ?from)
                       (at-curb ?front))
    :effect (and (not (car-clear ?front)) (car-clear ?from) (behind-car ?car ?front)
                 (not (behind-car ?car ?from))
                 (increase (total-cost) 1))))
