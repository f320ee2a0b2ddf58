; The Sussman anomaly: c is on a; build a on b on c. Optimal cost 6:
; unstack c a, put-down c, pick-up b, stack b c, pick-up a, stack a b.
(define (problem blocks-sussman)
  (:domain blocks)
  (:objects a b c - block)
  (:init (handempty) (on c a) (ontable a) (ontable b) (clear c) (clear b))
  (:goal (and (on a b) (on b c))))
