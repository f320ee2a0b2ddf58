; Two cities; p1 goes from the post office of c1 to that of c2, p2 from the
; airport of c1 to the post office of c2. Optimal cost 26: truck t1 takes p1
; to the airport (load 1, drive 3, unload 1), the plane takes both (loads 2,
; flight 10, unloads 2), truck t2 takes both to the post office (loads 2,
; drive 3, unloads 2).
(define (problem logistics-2)
  (:domain logistics)
  (:objects c1 c2 - city po1 po2 - location ap1 ap2 - airport
            t1 t2 - truck plane - airplane p1 p2 - package)
  (:init (in-city po1 c1) (in-city ap1 c1) (in-city po2 c2) (in-city ap2 c2)
    (at t1 po1) (at t2 ap2) (at plane ap1) (at p1 po1) (at p2 ap1)
    (= (flight-cost ap1 ap2) 10) (= (flight-cost ap2 ap1) 10)
    (= (flight-cost ap1 ap1) 0) (= (flight-cost ap2 ap2) 0)
    (= (total-cost) 0))
  (:goal (and (at p1 po2) (at p2 po2)))
  (:metric minimize (total-cost)))
